// SPDX-License-Identifier: Apache-2.0
// engine::execute: one vkCmdBuildClusterAccelerationStructureIndirectNV against a
// MemoryImage, exactly as the extension specifies, returning every range it read and
// wrote (execution_record.h).
//
// Semantics the engine fixes where the spec leaves freedom:
// - Ops run in parallel (TBB) in chunks of kOpsPerChunk; within a chunk every op reads
//   before any op writes, and writes land in op index order, so the bytes never depend on
//   the thread count (overlapping destinations: the higher op index wins, and a finding
//   says so).
// - Implicit destinations are packed from dstImplicitData in op index order, each object
//   at the next multiple of its type's alignment (properties) after the room the one before
//   takes: its own size, or ExecuteOptions::implicit_object_room where that is more (the
//   room past the object is written with zeros).
// - An indirected field (addressResolutionFlags) holds the address of a VkDeviceAddress
//   (srcInfosCount: of the uint32 count); a strided region keeps its stride and size.
// - Scratch holds a 16-byte (offset, size) entry per op: the implicit layout.
// - A failed op writes no object; in implicit mode its dstAddressesArray/dstSizesArray
//   entries are written as 0.
#pragma once

#include "clastrace/engine/execution_record.h"
#include "clastrace/engine/memory_image.h"
#include "clastrace/engine/object_directory.h"
#include "clastrace/engine/properties.h"
#include "clastrace/vk_cluster_abi.h"

#include <cstdint>
#include <functional>
#include <optional>
#include <string>

namespace clastrace::engine {

inline constexpr uint32_t kOpsPerChunk = 16384;

struct ExecuteOptions {
    EngineProperties properties = EngineProperties::nvidia_default();
    // Live objects across commands (replay keeps one). nullptr: a private directory for
    // this call, so only this command's moves and builds are tracked.
    ObjectDirectory* directory = nullptr;
    // Findings kept per rule per command; the rest are counted in one summary finding.
    uint32_t max_findings_per_rule = 64;
    // The maxAccelerationStructureCount the app sized its buffers with (10445); 0: the
    // command's own value.
    uint32_t queried_max_count = 0;
    // The sizes vkGetClusterAccelerationStructureBuildSizesNV answered for this command's
    // input (replay passes the trace's matching query, else the worst case it assumed). A
    // driver may touch all of them, so 12300 compares scratch with build_scratch_size and
    // 12302/12303 take scratch (and, implicit mode, dstImplicitData) at these sizes. Unset:
    // 12300 against the engine's own worst case, 12302/12303 on the bytes the engine used.
    struct AnsweredSizes {
        uint64_t build_scratch_size = 0;
        uint64_t acceleration_structure_size = 0;  // implicit: the whole region
        // Where they come from, as findings say it after the size: "answered by the trace's
        // vkGetClusterAccelerationStructureBuildSizesNV query for this input".
        std::string source;
    };
    std::optional<AnsweredSizes> answered_sizes;
    // 12305/12307 require a whole "device address range" (srcInfosArray's, dstAddressesArray's
    // elements) to come from buffers with a usage. The answer: the first byte of
    // [begin, end) that some buffer holds but no buffer with `usage` (or of unknown usage)
    // does, or nullopt. Replay passes its buffer list, aliased buffers included; without it
    // the engine asks the image's regions (one usage per region).
    std::function<std::optional<uint64_t>(uint64_t begin, uint64_t end, VkBufferUsageFlags usage)>
        first_without_usage;
    // Implicit destinations: the bytes each object takes at least (the next object starts at
    // the next aligned offset after them), and what dstSizesArray says it takes. The layer's
    // traceable cluster BLASes write the driver's BVH at each object's address, which may be
    // larger than the engine's object (capture/README.md "Traceable cluster BLASes"); replay
    // passes the value the trace recorded. 0: each object takes its own size.
    uint64_t implicit_object_room = 0;
};

ExecutionRecord execute(const VkClusterAccelerationStructureCommandsInfoNV& command,
                        MemoryImage& memory, const ExecuteOptions& options = {});

// Rules of the engine itself (no VUID names them).
inline constexpr const char* kRuleFindingsTruncated = "CLASTRACE-findings-truncated";
inline constexpr const char* kRuleDestinationOverlap = "CLASTRACE-destinations-overlap";
inline constexpr const char* kRuleDestinationMisaligned = "CLASTRACE-destination-misaligned";
inline constexpr const char* kRuleDestinationTooSmall =
    "CLASTRACE-explicit-destination-smaller-than-object";
inline constexpr const char* kRuleSrcInfosStride = "CLASTRACE-src-infos-stride-below-struct-size";
inline constexpr const char* kRuleMoveTypeMismatch =
    "CLASTRACE-moved-object-type-differs-from-input";
inline constexpr const char* kRuleMovedBytesAboveInput =
    "CLASTRACE-moved-bytes-above-maxMovedBytes";
inline constexpr const char* kRuleMoveOverlap = "CLASTRACE-move-overlaps-with-noMoveOverlap";
inline constexpr const char* kRuleIntraCommandHazard = "CLASTRACE-op-reads-what-another-op-writes";
inline constexpr const char* kRuleClusterCountAboveInput =
    "CLASTRACE-cluster-count-above-bottom-level-input";
inline constexpr const char* kRuleTotalAboveInput = "CLASTRACE-total-count-above-input";
inline constexpr const char* kRuleBottomLevelTooLarge = "CLASTRACE-bottom-level-over-4GiB";
inline constexpr const char* kRuleMissingSizesArray =
    "CLASTRACE-compute-sizes-without-dstSizesArray";
inline constexpr const char* kRuleMissingInput = "CLASTRACE-missing-op-input";
inline constexpr const char* kRuleScratchTooSmall =
    "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-scratchData-12300";
inline constexpr const char* kRuleScratchMisaligned =
    "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-scratchData-12301";

}  // namespace clastrace::engine
