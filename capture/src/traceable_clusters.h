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

#include <clastrace/engine/memory_image.h>
#include <clastrace/vk_cluster_abi.h>
#include <vulkan/vulkan.h>

#include <cstdint>
#include <memory>
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

// The BLAS ops of a command the engine just ran, read from its image: the destination of each
// and its clusters' triangles decoded from the engine's CLAS bytes. Ops of another type, with
// implicit destinations, or whose destination `host_of(address, room)` cannot place, are left out; `skipped`
// counts them with a reason in `why`.
struct TraceableBatch {
    std::vector<TraceableBlasGeometry> blases;
    uint32_t skipped = 0;
    std::string why;
};
template <class HostOf>
TraceableBatch traceable_batch(const VkClusterAccelerationStructureCommandsInfoNV& command,
                               const engine::MemoryImage& image, uint32_t op_count,
                               const HostOf& host_of);
// The non-template part: one op's geometry from the BLAS the engine wrote at `address`.
bool decode_cluster_blas(const engine::MemoryImage& image, uint64_t address,
                         TraceableBlasGeometry& out, std::string& why);

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
};

template <class HostOf>
TraceableBatch traceable_batch(const VkClusterAccelerationStructureCommandsInfoNV& command,
                               const engine::MemoryImage& image, uint32_t op_count,
                               const HostOf& host_of) {
    TraceableBatch batch;
    if (command.input.opType !=
        VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV)
        return batch;
    if (command.input.opMode !=
            VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_EXPLICIT_DESTINATIONS_NV ||
        command.addressResolutionFlags != 0) {
        batch.skipped = op_count;
        batch.why = "only explicit destinations without indirected addresses are traceable yet";
        return batch;
    }
    for (uint32_t i = 0; i < op_count; ++i) {
        TraceableBlasGeometry blas;
        std::string why;
        try {
            const engine::FieldRef where{"dstAddressesArray", int64_t(i)};
            blas.address =
                image.read<uint64_t>(engine::MemoryImage::strided_address(command.dstAddressesArray,
                                                                          i, 8, where),
                                     where);
        } catch (const engine::MemoryFault& fault) {
            why = fault.message;
        }
        if (why.empty() && blas.address != 0 && !(blas.host = host_of(blas.address, blas.room)))
            why = "its destination is in no host-addressed buffer";
        if (why.empty() && blas.address != 0 && decode_cluster_blas(image, blas.address, blas, why))
            batch.blases.push_back(std::move(blas));
        else if (blas.address != 0 || !why.empty()) {
            ++batch.skipped;
            batch.why = why;
        }
    }
    return batch;
}

}  // namespace clastrace::capture
