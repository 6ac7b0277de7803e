// SPDX-License-Identifier: Apache-2.0
// Bug (VK_KHR_acceleration_structure): the top level is built right after the bottom level it
// instances, in the same command buffer, with no barrier, so it may read the bottom level
// before its build is done. --fixed records BUILD/AS_WRITE -> BUILD/AS_READ between them.
#include "bug_gpu.h"

using namespace bug_programs;

namespace {

struct KhrCalls {
    PFN_vkGetAccelerationStructureBuildSizesKHR sizes;
    PFN_vkCreateAccelerationStructureKHR create;
    PFN_vkDestroyAccelerationStructureKHR destroy;
    PFN_vkGetAccelerationStructureDeviceAddressKHR address;
    PFN_vkCmdBuildAccelerationStructuresKHR build;
};

template <class F>
F device_call(Gpu& gpu, const char* name) {
    auto f = reinterpret_cast<F>(vkGetDeviceProcAddr(gpu.device, name));
    if (!f) unsupported(name);
    return f;
}

// A structure of `type` over one geometry, placed in a buffer of its own, with its scratch.
struct Structure {
    VkAccelerationStructureKHR handle = VK_NULL_HANDLE;
    Buffer storage, scratch;
    VkDeviceAddress address = 0;
    VkAccelerationStructureBuildGeometryInfoKHR build{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_BUILD_GEOMETRY_INFO_KHR};
};

void create(Gpu& gpu, const KhrCalls& khr, VkAccelerationStructureTypeKHR type,
            const VkAccelerationStructureGeometryKHR& geometry, Structure& s) {
    s.build.type = type;
    s.build.flags = VK_BUILD_ACCELERATION_STRUCTURE_PREFER_FAST_TRACE_BIT_KHR;
    s.build.mode = VK_BUILD_ACCELERATION_STRUCTURE_MODE_BUILD_KHR;
    s.build.geometryCount = 1;
    s.build.pGeometries = &geometry;
    const uint32_t primitives = 1;
    VkAccelerationStructureBuildSizesInfoKHR sizes{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_BUILD_SIZES_INFO_KHR};
    khr.sizes(gpu.device, VK_ACCELERATION_STRUCTURE_BUILD_TYPE_DEVICE_KHR, &s.build, &primitives,
              &sizes);
    s.storage = gpu.buffer(sizes.accelerationStructureSize);
    s.scratch = gpu.buffer(sizes.buildScratchSize);
    VkAccelerationStructureCreateInfoKHR info{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_CREATE_INFO_KHR};
    info.buffer = s.storage.buffer;
    info.size = sizes.accelerationStructureSize;
    info.type = type;
    vk_ok(khr.create(gpu.device, &info, nullptr, &s.handle), "vkCreateAccelerationStructureKHR");
    VkAccelerationStructureDeviceAddressInfoKHR where{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_DEVICE_ADDRESS_INFO_KHR};
    where.accelerationStructure = s.handle;
    s.address = khr.address(gpu.device, &where);
    s.build.dstAccelerationStructure = s.handle;
    s.build.scratchData.deviceAddress = s.scratch.address;
}

}  // namespace

int main(int argc, char** argv) {
    const bool fixed = has_flag(argc, argv, "--fixed");
    Gpu gpu;
    open(gpu, "khr_tlas_without_barrier");
    if (!gpu.khr_structures) unsupported(VK_KHR_ACCELERATION_STRUCTURE_EXTENSION_NAME);
    const KhrCalls khr{
        device_call<PFN_vkGetAccelerationStructureBuildSizesKHR>(
            gpu, "vkGetAccelerationStructureBuildSizesKHR"),
        device_call<PFN_vkCreateAccelerationStructureKHR>(gpu, "vkCreateAccelerationStructureKHR"),
        device_call<PFN_vkDestroyAccelerationStructureKHR>(gpu,
                                                           "vkDestroyAccelerationStructureKHR"),
        device_call<PFN_vkGetAccelerationStructureDeviceAddressKHR>(
            gpu, "vkGetAccelerationStructureDeviceAddressKHR"),
        device_call<PFN_vkCmdBuildAccelerationStructuresKHR>(
            gpu, "vkCmdBuildAccelerationStructuresKHR")};

    Buffer vertices = gpu.buffer(9 * sizeof(float));
    const float triangle[9] = {0, 0, 1, 1, 0, 1, 0, 1, 1};
    std::memcpy(vertices.host, triangle, sizeof triangle);
    VkAccelerationStructureGeometryKHR triangles{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_GEOMETRY_KHR};
    triangles.geometryType = VK_GEOMETRY_TYPE_TRIANGLES_KHR;
    triangles.flags = VK_GEOMETRY_OPAQUE_BIT_KHR;
    triangles.geometry.triangles.sType =
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_GEOMETRY_TRIANGLES_DATA_KHR;
    triangles.geometry.triangles.vertexFormat = VK_FORMAT_R32G32B32_SFLOAT;
    triangles.geometry.triangles.vertexData.deviceAddress = vertices.address;
    triangles.geometry.triangles.vertexStride = 3 * sizeof(float);
    triangles.geometry.triangles.maxVertex = 2;
    triangles.geometry.triangles.indexType = VK_INDEX_TYPE_NONE_KHR;
    Structure bottom;
    create(gpu, khr, VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR, triangles, bottom);

    Buffer instances = gpu.buffer(sizeof(VkAccelerationStructureInstanceKHR));
    VkAccelerationStructureInstanceKHR instance{};
    instance.transform.matrix[0][0] = instance.transform.matrix[1][1] =
        instance.transform.matrix[2][2] = 1.0f;
    instance.mask = 0xFF;
    instance.accelerationStructureReference = bottom.address;
    std::memcpy(instances.host, &instance, sizeof instance);
    VkAccelerationStructureGeometryKHR instanced{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_GEOMETRY_KHR};
    instanced.geometryType = VK_GEOMETRY_TYPE_INSTANCES_KHR;
    instanced.geometry.instances.sType =
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_GEOMETRY_INSTANCES_DATA_KHR;
    instanced.geometry.instances.data.deviceAddress = instances.address;
    Structure top;
    create(gpu, khr, VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_KHR, instanced, top);

    const VkAccelerationStructureBuildRangeInfoKHR one{1, 0, 0, 0};
    const VkAccelerationStructureBuildRangeInfoKHR* ranges = &one;
    VkCommandBuffer cb = gpu.begin();
    khr.build(cb, 1, &bottom.build, &ranges);
    if (fixed)
        memory_barrier(cb, VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                       VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR,
                       VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                       VK_ACCESS_2_ACCELERATION_STRUCTURE_READ_BIT_KHR);
    khr.build(cb, 1, &top.build, &ranges);
    gpu.submit_and_wait(cb);
    print_range("bottom_level", bottom.storage.address, bottom.storage.size);
    khr.destroy(gpu.device, top.handle, nullptr);
    khr.destroy(gpu.device, bottom.handle, nullptr);
    return 0;
}
