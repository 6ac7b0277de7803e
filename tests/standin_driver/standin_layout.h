// SPDX-License-Identifier: MIT
// The stand-in driver's own sizes and layout (README.md): what it answers to
// vkGetClusterAccelerationStructureBuildSizesNV and where it places implicit destinations.
// Every number differs from the engine's on purpose, as a vendor driver's would.
#pragma once

#include <clastrace/vk_cluster_abi.h>

#include <cstdint>
#include <vector>

namespace clastrace::standin {

// Implicit destinations start this far past dstImplicitData (a multiple of every alignment).
inline constexpr uint64_t kImplicitLeadingBytes = 4096;
// Bytes added after each object before the next alignment; counted in the size it reports.
inline constexpr uint64_t kObjectPaddingBytes = 192;
// Scratch past the engine's and the address table, which the stand-in claims and never uses.
inline constexpr uint64_t kScratchSlackBytes = 4096;

struct StandinSizes {
    uint64_t acceleration_structure_size = 0;
    uint64_t build_scratch_size = 0;
    uint64_t padded_object_size = 0;  // the worst single object, padded
};

// The stand-in's answer for `info` (the engine's worst cases, padded and enlarged).
StandinSizes standin_build_sizes(const VkClusterAccelerationStructureInputInfoNV& info);

// The size the stand-in reports for an object whose engine bytes are `engine_size`.
uint64_t padded_size(uint64_t engine_size, uint64_t alignment);

// Offset in scratch of the table of destination addresses the stand-in builds through
// (the engine's own scratch entries come first).
uint64_t address_table_offset(uint32_t max_count);

// Offsets from dstImplicitData of each op's object (sizes: the engine's, 0 for an op that
// produced nothing; its offset is then UINT64_MAX).
std::vector<uint64_t> implicit_offsets(const std::vector<uint64_t>& engine_sizes,
                                       uint64_t alignment);

}  // namespace clastrace::standin
