// SPDX-License-Identifier: Apache-2.0
// Traceable cluster BLASes (issue 21): on a driver where the layer proves it works (Mesa's
// lavapipe: device addresses are host pointers, one driver library behind every device), a served
// BUILD_CLUSTERS_BOTTOM_LEVEL op also gets a driver KHR BLAS written at its destination address,
// so the application's own top levels and rays traverse its cluster BLASes.
//
// The layer drives the driver library directly (its own VkInstance and VkDevice "B" through
// vk_icdGetInstanceProcAddr, below the loader and every layer): B imports the pages that hold a
// destination as host memory, places a KHR BLAS at the destination's offset and builds it from
// the clusters' triangles, one geometry per cluster reference. The engine's own bytes for the
// object stay in the engine's image, from which the capture records the command's outputs, so
// replay checks them byte for byte as before. See capture/README.md "Traceable cluster BLASes".
#pragma once

#include <clastrace/engine/execution_record.h>
#include <clastrace/engine/memory_image.h>
#include <clastrace/vk_cluster_abi.h>
#include <vulkan/vulkan.h>

#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

namespace clastrace::capture {

enum class TraceableMode { kOff, kOn, kAuto };

// CLASTRACE_TRACEABLE_CLUSTERS: "0" off, "1" on (a failed probe still leaves it off, with an
// error), "auto" or unset: on where the probe passes.
TraceableMode traceable_mode_from_environment();

// The triangles of one cluster BLAS as the driver builds them: geometry g is the cluster the
// application's reference g named (empty when that reference held no cluster), its triangles at
// their original indices within the cluster, 9 floats each (three xyz vertices).
struct TraceableBlasGeometry {
    uint64_t address = 0;     // the BLAS's destination address
    uint8_t* host = nullptr;  // where its bytes are in host memory (the app's, or staged)
    uint64_t room = 0;        // bytes from `host` to the end of the buffer holding it
    std::vector<std::vector<float>> clusters;
    // Per cluster, each triangle's geometry index (0xFFFFFFFF: inactive), for the ray check.
    std::vector<std::vector<uint32_t>> geometry_indices;
    // Set by TraceableDriver::build: the bytes of the driver's BVH from `address` (its
    // accelerationStructureSize), which the trace marks as the driver's.
    uint64_t driver_size = 0;
};

// The BLAS ops of a command the engine just ran, read from its image: the destination of each op
// as the engine's run resolved it (`ops`: ExecutionRecord::ops, so indirected address arrays and
// implicit destinations without a dstAddressesArray are known too) and its clusters' triangles
// decoded from the engine's CLAS bytes. Ops of another type, that failed, or whose destination
// `host_of(address, room)` cannot place, are left out; `skipped` counts the last kind with a
// reason in `why`. Implicit destinations have room for the driver's BLAS because the engine
// packed them with traceable_implicit_room (layer_state.h).
struct TraceableBatch {
    std::vector<TraceableBlasGeometry> blases;
    uint32_t skipped = 0;
    std::string why;
};
template <class HostOf>
TraceableBatch traceable_batch(const VkClusterAccelerationStructureCommandsInfoNV& command,
                               const engine::MemoryImage& image,
                               const std::vector<engine::OpResult>& ops, const HostOf& host_of);
// The non-template part: one op's geometry from the BLAS the engine wrote at `address`.
bool decode_cluster_blas(const engine::MemoryImage& image, uint64_t address,
                         TraceableBlasGeometry& out, std::string& why);

// The engine's bytes of each traceable BLAS, kept by address in layer memory (traceable_keep.cpp).
// The application's memory at a traceable BLAS holds the driver's BVH; a later served command
// that reads those bytes (a rebuild into the same room, a move) must see the engine's object
// there, as replay does. Each entry covers the driver's BVH range and keeps both versions: where
// the application's bytes are still the driver's, reads get the engine's. Thread-safe.
class TraceableEngineBytes {
public:
    struct Entry {
        std::vector<uint8_t> engine, driver;       // [address, address + driver.size())
        std::vector<std::vector<float>> clusters;  // as TraceableBlasGeometry, for a move
        std::vector<std::vector<uint32_t>> geometry_indices;
    };
    // After the driver built (or moved) a BLAS at `address`; ends every entry it overlaps.
    void keep(uint64_t address, Entry entry);
    // `bytes` were copied from the application's memory at [address, address + size): every
    // kept range in it whose bytes are still the driver's gets the engine's; an entry the
    // application overwrote is dropped.
    void overlay(uint64_t address, uint8_t* bytes, uint64_t size);
    // A copy of the entry at exactly `address`; false when none.
    bool find(uint64_t address, Entry& out) const;
    // The size of the driver's BVH kept at exactly `address`; 0 when none.
    uint64_t driver_size(uint64_t address) const;
    uint64_t kept_bytes() const;

private:
    mutable std::mutex mutex_;
    std::map<uint64_t, Entry> entries_;  // by address, disjoint
};

// A buffer of device B and its memory (allocated, or imported from host memory).
struct TraceableBuffer {
    VkBuffer buffer = VK_NULL_HANDLE;
    VkDeviceMemory memory = VK_NULL_HANDLE;
    VkDeviceAddress address = 0;
    void* mapped = nullptr;  // allocated ones only
};

// Device B: its own instance and device on the driver library behind the application's device.
class TraceableDriver {
public:
    // Loads the driver library holding `any_driver_function` (a device function of the
    // application's device as the next layer gives it), creates B on the physical device whose
    // deviceUUID is `device_uuid`, and proves the mode: a tiny BLAS built on B into imported host
    // memory has the address of that memory. Null (and `why`) when any of it fails.
    static std::unique_ptr<TraceableDriver> probe(PFN_vkVoidFunction any_driver_function,
                                                  const uint8_t device_uuid[VK_UUID_SIZE],
                                                  std::string& why);
    ~TraceableDriver();
    TraceableDriver(const TraceableDriver&) = delete;
    TraceableDriver& operator=(const TraceableDriver&) = delete;

    // The driver's BLAS size for `clusters` geometries of `triangles_per_cluster` triangles each
    // (the worst case a served size answer must cover); 0 when the driver does not answer.
    uint64_t blas_size(uint32_t clusters, uint32_t triangles_per_cluster);

    // Builds every BLAS of `batch` at its host bytes, one submission, and waits, setting each
    // one's driver_size. False (and `why`) when any step fails; BLASes built before the failure
    // stay.
    bool build(TraceableBatch& batch, std::string& why);
    // The mode's one line for the log.
    static constexpr const char* kModeMessage =
        "served cluster BLASes are traceable: the driver's BLAS is built at each destination";
    // The engine's bytes of the BLASes built (or moved) so far. Shared apart from the driver:
    // reads through served memory may outlive the device (a capture written at exit), and
    // must not keep device B (and the driver library) alive until then.
    TraceableEngineBytes& engine_bytes() { return *engine_bytes_; }
    std::shared_ptr<TraceableEngineBytes> shared_engine_bytes() const { return engine_bytes_; }

private:
    struct Functions;
    TraceableDriver();
    bool create_device(const uint8_t device_uuid[VK_UUID_SIZE], std::string& why);
    bool prove(std::string& why);
    bool allocate(VkDeviceSize size, VkBufferUsageFlags usage, void* import, TraceableBuffer& out,
                  std::string& why);
    void release(TraceableBuffer& owned);

    std::unique_ptr<Functions> vk_;
    void* library_ = nullptr;
    VkInstance instance_ = VK_NULL_HANDLE;
    VkPhysicalDevice physical_ = VK_NULL_HANDLE;
    VkDevice device_ = VK_NULL_HANDLE;
    VkQueue queue_ = VK_NULL_HANDLE;
    uint32_t queue_family_ = 0;
    VkCommandPool pool_ = VK_NULL_HANDLE;
    VkPhysicalDeviceMemoryProperties memory_{};
    uint64_t import_alignment_ = 4096;
    std::shared_ptr<TraceableEngineBytes> engine_bytes_ = std::make_shared<TraceableEngineBytes>();
};

template <class HostOf>
TraceableBatch traceable_batch(const VkClusterAccelerationStructureCommandsInfoNV& command,
                               const engine::MemoryImage& image,
                               const std::vector<engine::OpResult>& ops, const HostOf& host_of) {
    TraceableBatch batch;
    if (command.input.opType !=
        VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV)
        return batch;
    for (const engine::OpResult& op : ops) {
        if (!op.executed || op.dst_address == 0 ||
            op.dst_type != VK_CLUSTER_ACCELERATION_STRUCTURE_TYPE_CLUSTERS_BOTTOM_LEVEL_NV)
            continue;  // compute-sizes mode, or a failed op: nothing built
        TraceableBlasGeometry blas;
        blas.address = op.dst_address;
        std::string why;
        if (!(blas.host = host_of(blas.address, blas.room)))
            why = "its destination is in no host-addressed buffer";
        if (why.empty() && decode_cluster_blas(image, blas.address, blas, why))
            batch.blases.push_back(std::move(blas));
        else {
            ++batch.skipped;
            batch.why = why;
        }
    }
    return batch;
}

}  // namespace clastrace::capture
