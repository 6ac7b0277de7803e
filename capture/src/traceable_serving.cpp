// SPDX-License-Identifier: Apache-2.0
// The layer's side of traceable cluster BLASes (traceable_clusters.h): the probe at device
// creation, the served size answers that make room for the driver's BLAS, and the driver build
// in the pause after the engine's.
#include "layer_state.h"
#include "traceable_clusters.h"

#include "clastrace/capture/cluster_limits.h"
#include "clastrace/capture/served_build.h"

#include <algorithm>
#include <atomic>

namespace clastrace::capture {

void set_up_traceable_clusters(DeviceState& state) {
    const TraceableMode mode = traceable_mode_from_environment();
    if (!state.serving || !state.cluster_enabled || mode == TraceableMode::kOff) return;
    InstanceState& instance = *state.instance;
    // Only where the driver could: KHR structures and host-pointer imports (lavapipe-like).
    if (!driver_lists_extension(instance, state.physical_device,
                                VK_KHR_ACCELERATION_STRUCTURE_EXTENSION_NAME) ||
        !driver_lists_extension(instance, state.physical_device,
                                VK_EXT_EXTERNAL_MEMORY_HOST_EXTENSION_NAME)) {
        if (mode == TraceableMode::kOn)
            log_message(LogLevel::kError,
                        "traceable cluster BLASes: off (the driver lacks "
                        "VK_KHR_acceleration_structure or VK_EXT_external_memory_host)");
        return;
    }
    VkPhysicalDeviceIDProperties ids{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_ID_PROPERTIES};
    VkPhysicalDeviceProperties2 properties{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_PROPERTIES_2, &ids};
    instance.next.GetPhysicalDeviceProperties2(state.physical_device, &properties);
    std::string why;
    state.traceable =
        TraceableDriver::probe((PFN_vkVoidFunction)state.next.CreateBuffer, ids.deviceUUID, why);
    if (state.traceable)
        log_message(LogLevel::kInfo, "traceable cluster BLASes: on (%s)",
                    TraceableDriver::kModeMessage);
    else
        log_message(mode == TraceableMode::kOn ? LogLevel::kError : LogLevel::kInfo,
                    "traceable cluster BLASes: off (the probe failed: %s); served BLASes are in "
                    "the engine's layout only",
                    why.c_str());
}

void cover_traceable_blas(DeviceState& state,
                          const VkClusterAccelerationStructureInputInfoNV& input,
                          VkAccelerationStructureBuildSizesInfoKHR& sizes) {
    if (!state.traceable ||
        input.opType != VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV ||
        input.opMode != VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_EXPLICIT_DESTINATIONS_NV ||
        !input.opInput.pClustersBottomLevel)
        return;
    // The worst case: every cluster reference a cluster of the most triangles a cluster may have.
    const uint64_t driver = state.traceable->blas_size(
        input.opInput.pClustersBottomLevel->maxClusterCountPerAccelerationStructure,
        served_engine_properties().max_triangles_per_cluster);
    const uint64_t alignment = served_engine_properties().cluster_bottom_level_byte_alignment;
    sizes.accelerationStructureSize =
        (std::max<uint64_t>(sizes.accelerationStructureSize, driver) + alignment - 1) / alignment *
        alignment;
}

void build_traceable_blases(DeviceState& state, uint64_t pause_id,
                            const VkClusterAccelerationStructureCommandsInfoNV& command,
                            const engine::MemoryImage& image, const ServedMemory& memory,
                            uint32_t op_count,
                            std::vector<ClusterBuildCapture::DriverBvh>* driver_bvh) {
    if (!state.traceable) return;
    TraceableBatch batch =
        traceable_batch(command, image, op_count, [&](uint64_t address, uint64_t& room) {
            const ServedBuffer* b = memory.buffer_holding(address, 1);
            if (!b) return (uint8_t*)nullptr;
            room = b->size - (address - b->address);
            return b->host + (address - b->address);
        });
    std::string why;
    if (!state.traceable->build(batch, why))
        log_message(LogLevel::kError, "served build (pause %llu): the driver's BLASes: %s",
                    (unsigned long long)pause_id, why.c_str());
    else if (!batch.blases.empty()) {
        log_message(LogLevel::kDebug, "served build (pause %llu): %zu driver BLASes built",
                    (unsigned long long)pause_id, batch.blases.size());
        // The ray check traces top levels over them (their instances name these addresses).
        for (const TraceableBlasGeometry& blas : batch.blases) {
            state.nv_scene.observe_cluster_blas(blas.address, blas.clusters, blas.geometry_indices);
            // The record marks these bytes as the driver's (replay keeps the engine's there).
            if (driver_bvh) driver_bvh->push_back({blas.address, blas.driver_size});
        }
    }
    // Info, once per process: the engine's bytes are still right and the trace still exact; only
    // the driver's own rays miss these BLASes (capture/README.md "Traceable cluster BLASes").
    static std::atomic<bool> said{false};
    if (batch.skipped)
        log_message(said.exchange(true) ? LogLevel::kDebug : LogLevel::kInfo,
                    "served build (pause %llu): %u BLASes not traceable by the driver: %s",
                    (unsigned long long)pause_id, batch.skipped, batch.why.c_str());
}

}  // namespace clastrace::capture
