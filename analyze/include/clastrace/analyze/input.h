// SPDX-License-Identifier: Apache-2.0
// The analyzer's input model: what a trace plus its replay know about each command, region,
// object, build-sizes query, hazard and the trace file itself. Replay fills these and hands
// them to Analyzer one at a time (see analyzer.h for the order); nothing here owns GPU data.
#pragma once

#include <cstdint>
#include <optional>
#include <string>

namespace clastrace::analyze {

// Values 0..5 equal VkClusterAccelerationStructureOpTypeNV (checked in names.cpp);
// `other` stands for commands outside the cluster extension (legacy NV builds, copies).
enum class OpType : uint8_t {
    kMoveObjects = 0,
    kBuildClustersBottomLevel = 1,
    kBuildTriangleCluster = 2,
    kBuildTriangleClusterTemplate = 3,
    kInstantiateTriangleCluster = 4,
    kGetClusterTemplateIndices = 5,
    kOther = 6,
};
inline constexpr int kOpTypeCount = 7;

// Values 0..2 equal VkClusterAccelerationStructureOpModeNV; `none` for non-cluster commands.
enum class OpMode : uint8_t {
    kImplicitDestinations = 0,
    kExplicitDestinations = 1,
    kComputeSizes = 2,
    kNone = 3
};

// What a range of device addresses is used for. `buffer` is a container (a whole VkBuffer):
// it is drawn on the memory map but never counted as overlapping what it contains.
enum class RegionRole : uint8_t {
    kBuffer,
    kScratch,
    kImplicitData,
    kDstAddresses,
    kDstSizes,
    kSrcInfos,
    kSrcInfosCount,
    kObjectClas,
    kObjectTemplate,
    kObjectBlas,
    kVertex,
    kIndex,
    kOther,
};
inline constexpr int kRegionRoleCount = 13;

enum class ObjectType : uint8_t { kClas, kClusterTemplate, kBlas, kOther };

// One use of a device-address range by the command opened last (Analyzer::on_command).
// The same `id` reported by several commands is one region whose lifetime spans them.
struct RegionInfo {
    uint64_t id = 0;    // stable per region across the trace (replay's choice, e.g. a counter)
    std::string label;  // for people: "scratch of cmd 12", a buffer's debug name, ...
    uint64_t base = 0;  // device address of the first byte
    uint64_t size = 0;  // bytes; base + size must not pass 2^64
    RegionRole role = RegionRole::kOther;
    bool written =
        false;  // the command writes (some of) it; two reads of the same bytes never overlap
};

// A command as replay saw it. Opens a command: every region, object, build-sizes and hazard
// event that follows belongs to it, until the next on_command or finish().
struct CommandInfo {
    uint64_t ordinal = 0;     // strictly increasing over the trace, global over submissions
    uint64_t submission = 0;  // queue submission it was recorded into (non-decreasing)
    uint64_t command_buffer = 0;
    uint32_t index = 0;  // position inside its command buffer
    std::string name;    // "vkCmdBuildClusterAccelerationStructureIndirectNV", ...
    OpType op_type = OpType::kOther;
    OpMode op_mode = OpMode::kNone;
    uint64_t op_count = 0;   // ops actually performed (min of srcInfosCount and the max count)
    uint64_t triangles = 0;  // over all ops of the command
    std::optional<uint64_t> gpu_ns;     // captured GPU timestamps around the command, if any
    std::optional<uint64_t> replay_ns;  // replay engine time for the command
    std::optional<uint64_t> scratch_used_bytes;  // engine's scratch use, if it models one
    // Bytes from dstImplicitData / scratchData to the end of the buffer holding them, where the
    // trace binds that buffer. Unset: the sums of the command's implicit_data/scratch regions.
    std::optional<uint64_t> implicit_allocated_bytes;
    std::optional<uint64_t> scratch_allocated_bytes;
    // dstImplicitData bytes the build packed objects into (alignment gaps included). Unset: the
    // sum of the command's object bytes.
    std::optional<uint64_t> implicit_used_bytes;
    // Commands whose objects replay does not rebuild (legacy NV builds, deserialization): size
    // of the destination object the driver was asked for (memory requirements / create size).
    uint64_t driver_object_bytes = 0;
};

// One acceleration-structure object a command produced (one per op that wrote an object).
struct ObjectInfo {
    uint32_t op_index = 0;
    ObjectType type = ObjectType::kClas;
    uint64_t address = 0;
    uint64_t engine_bytes = 0;             // size of the engine's serialized object
    std::optional<uint64_t> driver_bytes;  // size the driver wrote to dstSizesArray, if captured
    std::optional<uint64_t> engine_bytes_untruncated;  // same object at positionTruncateBitCount 0
    uint64_t triangles = 0;
    uint64_t vertices = 0;
    uint32_t truncate_bits = 0;  // positionTruncateBitCount the object was built with
};

// vkGetClusterAccelerationStructureBuildSizesNV for the current command's input: the limits
// it was asked about and what it answered. In implicit mode acceleration_structure_size is the
// whole dstImplicitData need; in explicit mode it is the worst case of one object.
struct BuildSizesInfo {
    uint64_t max_acceleration_structure_count = 0;
    uint64_t max_total_triangles = 0;
    uint64_t max_total_vertices = 0;
    uint32_t max_cluster_triangles = 0;
    uint32_t max_cluster_vertices = 0;
    uint32_t min_position_truncate_bits = 0;
    uint64_t acceleration_structure_size = 0;
    uint64_t build_scratch_size = 0;
    uint64_t update_scratch_size = 0;
};

// A hazard replay reported while executing the current command (`second_command`).
struct HazardSummary {
    std::string hazard_class;  // replay's rule name, e.g. "WRITE_AFTER_WRITE" or a VUID string
    uint64_t first_command = 0;
    uint64_t second_command = 0;
    uint64_t base = 0;  // address range involved; size 0 means "not known"
    uint64_t size = 0;
    std::string message;
};

// Two GPU timestamps written into one command buffer and the commands recorded between them.
struct GpuSpan {
    uint64_t first_ordinal = 0, last_ordinal = 0;  // commands between the timestamps (ordinals)
    uint64_t commands = 0, ops = 0, triangles = 0;
    uint64_t start_ticks = 0;  // first timestamp, in device ticks
    uint64_t gpu_ns = 0;       // (end - start) ticks x timestamp period
};

// The device clock: VkPhysicalDeviceLimits::timestampPeriod and, if the capture recorded
// vkGetCalibratedTimestampsEXT, one pair tying device ticks to the host clock.
struct GpuClock {
    double timestamp_period_ns = 1.0;
    bool period_known = false;  // false: the trace header had no period; 1 ns per tick assumed
    std::optional<uint64_t> calibration_ticks, calibration_host_ns, calibration_max_deviation_ns;
};

struct TraceBytes {
    uint64_t raw = 0;           // payload bytes before deduplication
    uint64_t deduplicated = 0;  // after content deduplication
    uint64_t compressed = 0;    // on disk
};

}  // namespace clastrace::analyze
