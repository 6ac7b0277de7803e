// SPDX-License-Identifier: Apache-2.0
// vkGetClusterAccelerationStructureBuildSizesNV for the engine's byte formats.
//
// Per the spec: IMPLICIT_DESTINATIONS returns the object size for all
// maxAccelerationStructureCount results packed at their alignment, plus scratch;
// EXPLICIT_DESTINATIONS returns scratch for all of them and the size of a single object;
// COMPUTE_SIZES returns scratch only. Every size is a worst case over inputs within the
// limits of `input` (maxClusterTriangleCount, maxTotalTriangleCount, ...); execute()
// reports the slack between what it used and these bounds.
#pragma once

#include "clastrace/engine/finding.h"
#include "clastrace/engine/properties.h"
#include "clastrace/vk_cluster_abi.h"

#include <cstdint>
#include <vector>

namespace clastrace::engine {

struct BuildSizes {
    uint64_t acceleration_structure_size = 0;  // VkAccelerationStructureBuildSizesInfoKHR fields
    uint64_t build_scratch_size = 0;
    uint64_t update_scratch_size = 0;  // always 0: cluster ops have no update
    uint64_t single_object_size = 0;   // worst single object (whatever the mode)
    std::vector<Finding> findings;     // bad opType/opMode/opInput: sizes are 0
};

BuildSizes cluster_build_sizes(const VkClusterAccelerationStructureInputInfoNV& info,
                               const EngineProperties& properties);

// Scratch the engine uses for `op_count` ops of the command: a 16-byte (offset, size)
// entry per op, where execute() lays out the implicit destinations.
uint64_t scratch_bytes_for_ops(uint64_t op_count);

// The alignment of the objects an op type writes (properties), or 8 for template indices.
// The op type and the move input's type are the fields' 32 bits (common/enum_bits.h): neither
// need be checked yet.
uint64_t destination_alignment(uint32_t op_type, uint32_t move_type,
                               const EngineProperties& properties);

// Saturating helpers: sizes saturate at UINT64_MAX rather than wrap.
uint64_t sat_add(uint64_t a, uint64_t b);
uint64_t sat_mul(uint64_t a, uint64_t b);
uint64_t align_up_sat(uint64_t v, uint64_t alignment);

}  // namespace clastrace::engine
