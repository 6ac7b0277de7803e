// SPDX-License-Identifier: Apache-2.0
// Replay of the two older commands, vkCmdBuildAccelerationStructureNV and
// vkCmdCopyMemoryToAccelerationStructureKHR, and of the capture's RayQueryCheck records.
//
// Each VkAccelerationStructureNV/KHR the trace creates gets an engine object region of its
// own (a "shadow" at kShadowBase and up, sized by the engine's requirement), because the
// capturing driver sized the application's memory for its own format, not the engine's.
// The sync model sees the captured object ranges; the engine reads and writes the shadows.
// Driver handles (vkGetAccelerationStructureHandleNV, recorded as device_address on the
// creation record) translate to shadows wherever an instance record or a serialized handle
// list names them.
#pragma once

#include "replay_memory.h"
#include "sync_model_feed.h"

#include <clastrace/engine/nv_build.h>
#include <clastrace/replay/replay_report.h>
#include <clastrace/replay/replayer.h>
#include <clastrace/traces/records.h>
#include <clastrace/traces/trace_generated.h>

#include <functional>
#include <map>
#include <optional>
#include <unordered_map>

namespace clastrace::replay::detail {

using SnapshotVector = traces::SnapshotVector;

struct NvReplayContext {
    ReplayMemory& memory;
    ReplayReport& report;
    SyncModelFeed& sync;
    const ReplayOptions& options;
    std::function<void(ReplayFinding)> add_finding;
    std::function<void(const SnapshotVector*, const ReplayLocation&)> lay_in_snapshots;
    // Hands the engine's record of a command (and its engine time) to a replay observer.
    std::function<void(engine::ExecutionRecord&&, uint64_t engine_ns)> observe;
};

class NvReplay {
public:
    explicit NvReplay(NvReplayContext context) : c_(std::move(context)) {}

    // The capturing device: its VkPhysicalDeviceRayTracingPropertiesNV limits (0: keep the
    // default) and whether VK_KHR_acceleration_structure was enabled (when the trace lists
    // the enabled extensions).
    void set_device(const fbs::DeviceInfo& device);
    void on_create(const fbs::AccelerationStructureCreate& create);
    void on_requirement(const fbs::AccelerationStructureMemoryRequirementsNV& requirement);
    void on_bind(const fbs::AccelerationStructureBindMemory& bind);
    void build(const fbs::CmdBuildAccelerationStructureNV& build, const CommandRef& ref,
               const ReplayLocation& where);
    void deserialize(const fbs::CmdCopyMemoryToAccelerationStructure& copy, const CommandRef& ref,
                     const ReplayLocation& where);
    void ray_check(const fbs::RayQueryCheck& check);
    // The shadow holding the engine's build of `handle`, or 0 when none is built (ReplayObserver).
    uint64_t built_shadow(uint64_t handle) const {
        const auto it = objects_.find(handle);
        return it != objects_.end() && it->second.built && !it->second.opaque ? it->second.shadow
                                                                              : 0;
    }

    static constexpr uint64_t kShadowBase = 0xE000'0000'0000'0000ull;
    // Bytes all shadows together may take (hostile creation counts end here).
    static constexpr uint64_t kShadowBudget = 4ull << 30;

private:
    friend class KhrReplay;  // KHR objects share these objects, shadows and translations
    struct Object {
        uint64_t handle = 0;
        bool nv = true;
        std::optional<engine::NvObjectInfo> created;
        uint64_t driver_handle = 0;  // the 64-bit handle instance records and handle lists carry
        uint64_t khr_size = 0;       // KHR objects: the size they were created with
        bool bound = false;
        uint64_t shadow = 0;  // 0: none yet
        uint64_t shadow_size = 0;
        bool built = false;
        bool opaque = false;  // deserialized from another driver's blob
        uint32_t built_flags = 0;
        uint64_t driver_object = 0, driver_build_scratch = 0, driver_update_scratch = 0;
    };
    Object* object(uint64_t handle);
    bool ensure_shadow(Object& o, const ReplayLocation& where, uint64_t at_least = 0);
    engine::NvObjectBinding binding(Object& o, const ReplayLocation& where);
    // A build's dst and src bound into `cmd` (findings for unknown handles); dst, or null.
    Object* bind_build_structures(const fbs::CmdBuildAccelerationStructureNV& build,
                                  engine::NvBuildCommand& cmd, const ReplayLocation& where);
    // The build's sizes beside the driver's, for the report (NvSizeComparison).
    void note_sizes(const Object& dst, const engine::NvBuildCommand& cmd,
                    const engine::ExecutionRecord& record, const ReplayLocation& where);
    std::optional<uint64_t> resolve(uint64_t driver_handle, bool bottom_only);
    void feed(const CommandRef& ref, const engine::ExecutionRecord& record,
              const ReplayLocation& where);
    void engine_findings(const engine::ExecutionRecord& record, const ReplayLocation& where);

    NvReplayContext c_;
    engine::NvLimits limits_;
    bool khr_acceleration_structure_missing_ = false;
    std::unordered_map<uint64_t, Object> objects_;
    std::unordered_map<uint64_t, uint64_t> by_driver_handle_;  // driver handle -> object handle
    std::map<uint64_t, uint64_t> shadow_owner_;                // shadow base -> object handle
    uint64_t next_shadow_ = kShadowBase;
};

}  // namespace clastrace::replay::detail
