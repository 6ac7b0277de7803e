// SPDX-License-Identifier: Apache-2.0
// Bug (VK_KHR_acceleration_structure): a bottom level is serialized once (the engine's cache on
// disk); a later run loads the blob into a staging buffer, copies it to device memory with
// vkCmdCopyBuffer and deserializes it (vkCmdCopyMemoryToAccelerationStructureKHR) right after
// the copy with no barrier, so the deserialize may read a blob the copy has not written.
// --fixed records COPY/TRANSFER_WRITE -> ACCELERATION_STRUCTURE_BUILD/TRANSFER_READ between.
#include "bug_khr.h"

using namespace bug_programs;

namespace {

struct SerializeCalls {
    PFN_vkCmdWriteAccelerationStructuresPropertiesKHR write_properties;
    PFN_vkCmdCopyAccelerationStructureToMemoryKHR serialize;
    PFN_vkCmdCopyMemoryToAccelerationStructureKHR deserialize;
};

// The serialized size of `s`, asked of the device through a query.
VkDeviceSize serialized_size(Gpu& gpu, const SerializeCalls& calls, const Structure& s) {
    VkQueryPoolCreateInfo pool_info{VK_STRUCTURE_TYPE_QUERY_POOL_CREATE_INFO};
    pool_info.queryType = VK_QUERY_TYPE_ACCELERATION_STRUCTURE_SERIALIZATION_SIZE_KHR;
    pool_info.queryCount = 1;
    VkQueryPool pool = VK_NULL_HANDLE;
    vk_ok(vkCreateQueryPool(gpu.device, &pool_info, nullptr, &pool), "vkCreateQueryPool");
    VkCommandBuffer cb = gpu.begin();
    vkCmdResetQueryPool(cb, pool, 0, 1);
    calls.write_properties(cb, 1, &s.handle,
                           VK_QUERY_TYPE_ACCELERATION_STRUCTURE_SERIALIZATION_SIZE_KHR, pool, 0);
    gpu.submit_and_wait(cb);
    uint64_t size = 0;
    vk_ok(vkGetQueryPoolResults(gpu.device, pool, 0, 1, sizeof size, &size, sizeof size,
                                VK_QUERY_RESULT_64_BIT | VK_QUERY_RESULT_WAIT_BIT),
          "vkGetQueryPoolResults");
    vkDestroyQueryPool(gpu.device, pool, nullptr);
    return size;
}

}  // namespace

int main(int argc, char** argv) {
    const bool fixed = has_flag(argc, argv, "--fixed");
    Gpu gpu;
    open(gpu, "khr_deserialize_no_barrier");
    const KhrCalls khr = load_khr(gpu);
    const SerializeCalls calls{device_call<PFN_vkCmdWriteAccelerationStructuresPropertiesKHR>(
                                   gpu, "vkCmdWriteAccelerationStructuresPropertiesKHR"),
                               device_call<PFN_vkCmdCopyAccelerationStructureToMemoryKHR>(
                                   gpu, "vkCmdCopyAccelerationStructureToMemoryKHR"),
                               device_call<PFN_vkCmdCopyMemoryToAccelerationStructureKHR>(
                                   gpu, "vkCmdCopyMemoryToAccelerationStructureKHR")};

    Buffer vertices = gpu.buffer(kTriangleBytes);
    const VkAccelerationStructureGeometryKHR triangles = triangle_geometry(vertices);
    Structure original, loaded;
    create(gpu, khr, VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR, triangles, original);
    create(gpu, khr, VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR, triangles, loaded);
    VkCommandBuffer build = gpu.begin();
    cmd_build(khr, build, original);
    gpu.submit_and_wait(build);

    // The first run: serialize to memory the host then keeps (the disk cache).
    const VkDeviceSize blob_size = serialized_size(gpu, calls, original);
    Buffer disk = gpu.buffer(blob_size);
    VkCommandBuffer save = gpu.begin();
    VkCopyAccelerationStructureToMemoryInfoKHR to_memory{
        VK_STRUCTURE_TYPE_COPY_ACCELERATION_STRUCTURE_TO_MEMORY_INFO_KHR};
    to_memory.src = original.handle;
    to_memory.dst.deviceAddress = disk.address;
    to_memory.mode = VK_COPY_ACCELERATION_STRUCTURE_MODE_SERIALIZE_KHR;
    calls.serialize(save, &to_memory);
    gpu.submit_and_wait(save);

    // The later run: the blob goes through a staging copy into device memory, then back into
    // a structure.
    Buffer staging = gpu.buffer(blob_size);
    std::memcpy(staging.host, disk.host, blob_size);
    Buffer blob = gpu.buffer(blob_size);
    VkCommandBuffer load = gpu.begin();
    const VkBufferCopy whole{0, 0, blob_size};
    vkCmdCopyBuffer(load, staging.buffer, blob.buffer, 1, &whole);
    if (fixed)
        memory_barrier(load, VK_PIPELINE_STAGE_2_COPY_BIT, VK_ACCESS_2_TRANSFER_WRITE_BIT,
                       VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                       VK_ACCESS_2_TRANSFER_READ_BIT);
    VkCopyMemoryToAccelerationStructureInfoKHR from_memory{
        VK_STRUCTURE_TYPE_COPY_MEMORY_TO_ACCELERATION_STRUCTURE_INFO_KHR};
    from_memory.src.deviceAddress = blob.address;
    from_memory.dst = loaded.handle;
    from_memory.mode = VK_COPY_ACCELERATION_STRUCTURE_MODE_DESERIALIZE_KHR;
    calls.deserialize(load, &from_memory);
    gpu.submit_and_wait(load);
    print_range("blob", blob.address, blob_size);
    khr.destroy(gpu.device, loaded.handle, nullptr);
    khr.destroy(gpu.device, original.handle, nullptr);
    return 0;
}
