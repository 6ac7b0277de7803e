// SPDX-License-Identifier: Apache-2.0
// Replay of VK_KHR_acceleration_structure's commands on the engine: vkCmdBuildAcceleration-
// StructuresKHR (direct and indirect, the ranges as read at execution), vkCmdCopyAcceleration-
// StructureKHR/NV (clone, compact), vkCmdCopyAccelerationStructureToMemoryKHR (serialize) and
// vkCmdWriteAccelerationStructuresPropertiesKHR/NV, whose answers are compared with what the
// driver answered (QueryPoolResults) as notes: the engine's layout is its own by design.
//
// KHR objects share NvReplay's objects and shadows (nv_command.h): an object created at a
// device address gets an engine region of its own, the sync model sees the captured range.
// An instance's accelerationStructureReference resolves, in this order, to the shadow of the
// KHR or NV object created with that address, to where a replayed cluster build rebuilt the
// cluster BLAS the capture saw at that address (AddressTranslation), or (a trace the engine
// made) to the address itself; anything else names no bottom level.
#pragma once

#include "cluster_command.h"
#include "nv_command.h"

#include <clastrace/engine/khr_build.h>

#include <cstdint>
#include <map>
#include <optional>
#include <unordered_map>
#include <utility>

namespace clastrace::replay::detail {

struct KhrReplayContext {
    NvReplay& nv;
    AddressTranslation& translation;
};

class KhrReplay {
public:
    explicit KhrReplay(KhrReplayContext context) : k_(context) {}

    void on_create(const fbs::AccelerationStructureCreate& create);
    void build(const fbs::CmdBuildAccelerationStructuresKHR& build, const CommandRef& ref,
               const ReplayLocation& where);
    void copy(const fbs::CmdCopyAccelerationStructure& copy, const CommandRef& ref,
              const ReplayLocation& where);
    void copy_to_memory(const fbs::CmdCopyAccelerationStructureToMemory& copy,
                        const CommandRef& ref, const ReplayLocation& where);
    void write_properties(const fbs::CmdWriteAccelerationStructuresProperties& query,
                          const CommandRef& ref, const ReplayLocation& where);
    // The driver's answers, compared with the engine's (notes).
    void query_results(const fbs::QueryPoolResults& results);
    // A driver's vkGetAccelerationStructureBuildSizesKHR answer: the scratch its builds claim.
    void build_sizes(const fbs::GetAccelerationStructureBuildSizesKHR& sizes);

    // accelerationStructureReference -> the engine address of a bottom level (nullopt: none).
    std::optional<uint64_t> resolve_reference(uint64_t reference);

private:
    struct Answer {
        uint64_t value = 0;
        uint64_t acceleration_structure = 0;
        uint32_t query_type = 0;
        ReplayLocation where;
    };
    engine::KhrObject khr_object(uint64_t handle, const char* field, uint64_t at_least,
                                 const ReplayLocation& where);
    engine::KhrBuildInfo build_info(const fbs::AccelerationStructureBuildInfoKHR& in,
                                    const std::string& field, const ReplayLocation& where);
    uint64_t bytes_to_end_of_buffer(uint64_t address) const;
    // The engine object in `handle`'s shadow: its size (0 when it holds none) and kind.
    uint64_t engine_object_size(uint64_t handle, bool* top_level = nullptr);
    void mark_built(uint64_t handle, uint32_t flags);
    uint64_t driver_scratch(const fbs::AccelerationStructureBuildInfoKHR& in,
                            const std::vector<uint32_t>& counts) const;
    void note(std::string rule, std::string message, const ReplayLocation& where);

    KhrReplayContext k_;
    std::unordered_map<uint64_t, uint32_t> types_;  // object -> VkAccelerationStructureTypeKHR
    std::map<std::pair<uint64_t, uint32_t>, Answer> answers_;  // (pool, query) -> engine answer
    struct DriverSizes {
        uint32_t type = 0;
        std::vector<uint32_t> geometry_types, max_primitive_counts;
        uint64_t build_scratch = 0, update_scratch = 0;
    };
    std::vector<DriverSizes> driver_sizes_;
};

inline constexpr const char* kRuleKhrQueryAnswer = "CLASTRACE-replay-khr-query-answer-differs";
inline constexpr const char* kRuleKhrUnknownObject = "CLASTRACE-replay-khr-unknown-object";

}  // namespace clastrace::replay::detail
