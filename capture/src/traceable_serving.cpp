// SPDX-License-Identifier: Apache-2.0
// The layer's side of traceable cluster BLASes (traceable_clusters.h): the probe at device
// creation, the served size answers that make room for the driver's BLAS, and the driver build
// in the pause after the engine's.
#include "layer_state.h"
#include "traceable_clusters.h"

#include "clastrace/capture/capture_cost.h"
#include "clastrace/capture/cluster_limits.h"
#include "clastrace/capture/served_build.h"
#include "clastrace/engine/build_sizes.h"

#include <algorithm>
#include <atomic>
#include <cstring>
#include <functional>
#include <vector>

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

namespace {

// The bytes one cluster BLAS of `input` may need at its address: the engine's worst object and
// the driver's BLAS for the worst case (every cluster reference a cluster of the most triangles
// a cluster may have), aligned. 0 where `input` builds no cluster BLASes.
uint64_t traceable_blas_room(DeviceState& state,
                             const VkClusterAccelerationStructureInputInfoNV& input) {
    if (!state.traceable ||
        input.opType != VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV ||
        !input.opInput.pClustersBottomLevel)
        return 0;
    const engine::EngineProperties& properties = served_engine_properties();
    const VkClusterAccelerationStructureClustersBottomLevelInputNV& in =
        *input.opInput.pClustersBottomLevel;
    const uint64_t driver = state.traceable->blas_size(in.maxClusterCountPerAccelerationStructure,
                                                       properties.max_triangles_per_cluster);
    VkClusterAccelerationStructureInputInfoNV one = input;
    one.opMode = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_EXPLICIT_DESTINATIONS_NV;
    const uint64_t engine = engine::cluster_build_sizes(one, properties).single_object_size;
    const uint64_t alignment = properties.cluster_bottom_level_byte_alignment;
    return engine::align_up_sat(std::max(engine, driver), alignment);
}

bool moves_cluster_blases(const VkClusterAccelerationStructureCommandsInfoNV& command) {
    return command.input.opType == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV &&
           command.input.opInput.pMoveObjects &&
           command.input.opInput.pMoveObjects->type ==
               VK_CLUSTER_ACCELERATION_STRUCTURE_TYPE_CLUSTERS_BOTTOM_LEVEL_NV;
}

// Reads `size` bytes at a device address into `out`; false where they are not all there.
using ReadDeviceBytes = std::function<bool(uint64_t address, void* out, uint64_t size)>;

// `value` of a command field after the field's indirection (`bit` of addressResolutionFlags: the
// field holds the address of the value, as engine/execute.h reads it); 0 where that cell cannot
// be read.
uint64_t resolved_field(const VkClusterAccelerationStructureCommandsInfoNV& command, uint32_t bit,
                        uint64_t value, const ReadDeviceBytes& read) {
    if (!(command.addressResolutionFlags & bit) || value == 0) return value;
    uint64_t resolved = 0;
    return read(value, &resolved, sizeof resolved) ? resolved : 0;
}

// A move's source addresses (srcInfosArray[i].srcAccelerationStructure) for its first `count`
// ops, through the indirections the command asks for; 0 where an entry cannot be read.
std::vector<uint64_t> move_sources(const VkClusterAccelerationStructureCommandsInfoNV& command,
                                   uint32_t count, const ReadDeviceBytes& read) {
    const uint64_t base = resolved_field(
        command,
        VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_SRC_INFOS_ARRAY_BIT_NV,
        command.srcInfosArray.deviceAddress, read);
    const uint64_t stride = command.srcInfosArray.stride ? command.srcInfosArray.stride : 8;
    std::vector<uint64_t> sources(count, 0);
    for (uint32_t i = 0; i < count && base != 0; ++i)
        if (!read(base + i * stride, &sources[i], 8)) sources[i] = 0;
    return sources;
}

// How many ops a command will run, read before the engine runs it: srcInfosCount's value (through
// its indirection) capped by maxAccelerationStructureCount; the max where it cannot be read.
uint32_t op_count_before_run(const VkClusterAccelerationStructureCommandsInfoNV& command,
                             const ReadDeviceBytes& read) {
    const uint32_t max = command.input.maxAccelerationStructureCount;
    const uint64_t at = resolved_field(
        command,
        VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_SRC_INFOS_COUNT_BIT_NV,
        command.srcInfosCount, read);
    uint32_t count = max;  // srcInfosCount 0: the max
    if (at != 0 && read(at, &count, 4)) count = std::min(count, max);
    return count;
}

// A move of cluster BLASes: the largest driver BVH among the traceable BLASes it moves (their
// sources read from the application's memory before the engine runs, indirections followed), 0
// when it moves none.
uint64_t moved_blas_room(DeviceState& state,
                         const VkClusterAccelerationStructureCommandsInfoNV& command,
                         const ServedMemory& memory) {
    if (!state.traceable || !moves_cluster_blases(command)) return 0;
    const ReadDeviceBytes read = [&](uint64_t address, void* out, uint64_t size) {
        const ServedBuffer* b = address ? memory.buffer_holding(address, size) : nullptr;
        if (b) std::memcpy(out, b->host + (address - b->address), size);
        return b != nullptr;
    };
    uint64_t room = 0;
    for (uint64_t src : move_sources(command, op_count_before_run(command, read), read))
        if (src != 0) room = std::max(room, state.traceable->engine_bytes().driver_size(src));
    const uint64_t alignment = served_engine_properties().cluster_bottom_level_byte_alignment;
    return engine::align_up_sat(room, alignment);
}

}  // namespace

uint64_t traceable_implicit_room(DeviceState& state,
                                 const VkClusterAccelerationStructureCommandsInfoNV& command,
                                 const ServedMemory& memory) {
    if (command.input.opMode !=
            VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV ||
        !state.traceable)
        return 0;
    return moves_cluster_blases(command) ? moved_blas_room(state, command, memory)
                                         : traceable_blas_room(state, command.input);
}

void cover_traceable_blas(DeviceState& state,
                          const VkClusterAccelerationStructureInputInfoNV& input,
                          VkAccelerationStructureBuildSizesInfoKHR& sizes) {
    const uint64_t room = traceable_blas_room(state, input);
    if (room == 0) return;
    if (input.opMode == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_EXPLICIT_DESTINATIONS_NV)
        sizes.accelerationStructureSize = std::max<uint64_t>(sizes.accelerationStructureSize, room);
    else if (input.opMode == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV)
        // The whole implicit data: each of the objects takes `room` (the room covers the engine's
        // worst object, so every object starts `room` after the one before).
        sizes.accelerationStructureSize =
            std::max(sizes.accelerationStructureSize,
                     engine::sat_mul(input.maxAccelerationStructureCount, room));
}

void overlay_traceable_bytes(DeviceState& state, ServedMemory& memory) {
    if (!state.traceable) return;
    std::shared_ptr<TraceableEngineBytes> kept = state.traceable->shared_engine_bytes();
    memory.set_host_overlay([kept](uint64_t address, uint8_t* bytes, uint64_t size) {
        kept->overlay(address, bytes, size);
    });
}

namespace {

// The image's bytes [address, address + size) (the engine's view), or empty when one region
// does not hold them.
std::vector<uint8_t> image_bytes(const engine::MemoryImage& image, uint64_t address,
                                 uint64_t size) {
    const engine::MemoryRegion* region = image.find_region(address);
    if (!region || address + size > region->base + region->size) return {};
    const auto* from =
        reinterpret_cast<const uint8_t*>(region->bytes.data()) + (address - region->base);
    return {from, from + size};
}

// Keeps the engine's and the driver's bytes of a BLAS the driver just wrote at `host`.
void keep_engine_bytes(TraceableDriver& driver, const engine::MemoryImage& image, uint64_t address,
                       const uint8_t* host, uint64_t size, TraceableEngineBytes::Entry entry) {
    entry.engine = image_bytes(image, address, size);
    if (entry.engine.size() != size) return;
    entry.driver.assign(host, host + size);
    driver.engine_bytes().keep(address, std::move(entry));
}

// The image's bytes as a ReadDeviceBytes (the engine's view after its run).
ReadDeviceBytes image_reader(const engine::MemoryImage& image) {
    return [&image](uint64_t address, void* out, uint64_t size) {
        const engine::MemoryRegion* region = image.find_region(address);
        if (!region || address + size < address || address + size > region->base + region->size)
            return false;
        std::memcpy(out, region->bytes.data() + (address - region->base), size);
        return true;
    };
}

// MOVE_OBJECTS of cluster BLASes: each moved traceable BLAS's driver BVH is copied to where the
// engine moved its object (`ops`: the run's destinations, explicit or implicit, whatever the
// command's indirections; lavapipe's BVH survives a plain copy). The number moved; `why` says why
// one was not.
uint32_t move_traceable_blases(DeviceState& state,
                               const VkClusterAccelerationStructureCommandsInfoNV& command,
                               const engine::MemoryImage& image, const ServedMemory& memory,
                               const std::vector<engine::OpResult>& ops,
                               std::vector<ClusterBuildCapture::DriverBvh>* driver_bvh,
                               std::string& why) {
    uint32_t moved = 0;
    const std::vector<uint64_t> sources =
        move_sources(command, uint32_t(ops.size()), image_reader(image));
    for (size_t i = 0; i < ops.size(); ++i) {
        const uint64_t src = sources[i], dst = ops[i].executed ? ops[i].dst_address : 0;
        TraceableEngineBytes::Entry entry;
        if (src == 0 || dst == 0 || !state.traceable->engine_bytes().find(src, entry))
            continue;  // not a traceable BLAS (or its bytes were overwritten since)
        const uint64_t size = entry.driver.size();
        const ServedBuffer* b = memory.buffer_holding(dst, size);
        if (!b) {
            why = "the driver's BVH (" + std::to_string(size) +
                  " bytes) does not fit in the buffer at the move's destination";
            continue;
        }
        uint8_t* host = b->host + (dst - b->address);
        std::memcpy(host, entry.driver.data(), size);
        state.nv_scene.observe_cluster_blas(dst, entry.clusters, entry.geometry_indices);
        if (driver_bvh) driver_bvh->push_back({dst, size});
        keep_engine_bytes(*state.traceable, image, dst, host, size, std::move(entry));
        ++moved;
    }
    return moved;
}

// A served move of cluster BLASes: the driver's BVHs move too, to explicit destinations or to
// implicit ones (the engine gave each the room of the largest moved driver BVH: moved_blas_room).
void move_driver_bvhs(DeviceState& state, uint64_t pause_id,
                      const VkClusterAccelerationStructureCommandsInfoNV& command,
                      const engine::MemoryImage& image, const ServedMemory& memory,
                      const std::vector<engine::OpResult>& ops,
                      std::vector<ClusterBuildCapture::DriverBvh>* driver_bvh) {
    if (command.input.opMode == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_COMPUTE_SIZES_NV) return;
    std::string why;
    const uint32_t moved =
        move_traceable_blases(state, command, image, memory, ops, driver_bvh, why);
    log_message(why.empty() ? LogLevel::kDebug : LogLevel::kInfo,
                "served move (pause %llu): %u driver BVHs moved%s%s", (unsigned long long)pause_id,
                moved, why.empty() ? "" : "; not moved: ", why.c_str());
}

}  // namespace

void build_traceable_blases(DeviceState& state, uint64_t pause_id,
                            const VkClusterAccelerationStructureCommandsInfoNV& command,
                            const engine::MemoryImage& image, const ServedMemory& memory,
                            const std::vector<engine::OpResult>& ops,
                            std::vector<ClusterBuildCapture::DriverBvh>* driver_bvh) {
    if (!state.traceable) return;
    if (moves_cluster_blases(command))
        return move_driver_bvhs(state, pause_id, command, image, memory, ops, driver_bvh);
    TraceableBatch batch =
        traceable_batch(command, image, ops, [&](uint64_t address, uint64_t& room) {
            const ServedBuffer* b = memory.buffer_holding(address, 1);
            if (!b) return (uint8_t*)nullptr;
            room = b->size - (address - b->address);
            return b->host + (address - b->address);
        });
    std::string why;
    const uint64_t started_wall = wall_ns(), started_cpu = thread_cpu_ns();
    const bool built = state.traceable->build(batch, why);
    if (!batch.blases.empty())
        add_cost(CostPhase::kDriverBlas, wall_ns() - started_wall, thread_cpu_ns() - started_cpu);
    if (!built)
        log_message(LogLevel::kError, "served build (pause %llu): the driver's BLASes: %s",
                    (unsigned long long)pause_id, why.c_str());
    else if (!batch.blases.empty()) {
        // The ray check traces top levels over them (their instances name these addresses).
        for (const TraceableBlasGeometry& blas : batch.blases) {
            state.nv_scene.observe_cluster_blas(blas.address, blas.clusters, blas.geometry_indices);
            // The record marks these bytes as the driver's (replay keeps the engine's there).
            if (driver_bvh) driver_bvh->push_back({blas.address, blas.driver_size});
            // A later served command that reads these bytes (a rebuild, a move) gets the
            // engine's, as replay does.
            keep_engine_bytes(*state.traceable, image, blas.address, blas.host, blas.driver_size,
                              {{}, {}, blas.clusters, blas.geometry_indices});
        }
        log_message(LogLevel::kDebug,
                    "served build (pause %llu): %zu driver BLASes built (engine and driver bytes "
                    "of traceable BLASes kept: %llu)",
                    (unsigned long long)pause_id, batch.blases.size(),
                    (unsigned long long)state.traceable->engine_bytes().kept_bytes());
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
