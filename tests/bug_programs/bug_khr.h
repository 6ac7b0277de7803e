// SPDX-License-Identifier: Apache-2.0
// VK_KHR_acceleration_structure the way the bug programs' outside engine uses it: the entry
// points it loads, and one structure over one geometry in a buffer of its own.
#pragma once

#include "bug_gpu.h"

namespace bug_programs {

struct KhrCalls {
    PFN_vkGetAccelerationStructureBuildSizesKHR sizes;
    PFN_vkCreateAccelerationStructureKHR create;
    PFN_vkDestroyAccelerationStructureKHR destroy;
    PFN_vkGetAccelerationStructureDeviceAddressKHR address;
    PFN_vkCmdBuildAccelerationStructuresKHR build;
};

template <class F>
inline F device_call(Gpu& gpu, const char* name) {
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

inline void create(Gpu& gpu, const KhrCalls& khr, VkAccelerationStructureTypeKHR type,
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


// One triangle's vertices (float3, no indices) in `vertices`, as the geometry of a bottom level.
inline VkAccelerationStructureGeometryKHR triangle_geometry(const Buffer& vertices) {
    const float triangle[9] = {0, 0, 1, 1, 0, 1, 0, 1, 1};
    std::memcpy(vertices.host, triangle, sizeof triangle);
    VkAccelerationStructureGeometryKHR g{VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_GEOMETRY_KHR};
    g.geometryType = VK_GEOMETRY_TYPE_TRIANGLES_KHR;
    g.flags = VK_GEOMETRY_OPAQUE_BIT_KHR;
    g.geometry.triangles.sType =
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_GEOMETRY_TRIANGLES_DATA_KHR;
    g.geometry.triangles.vertexFormat = VK_FORMAT_R32G32B32_SFLOAT;
    g.geometry.triangles.vertexData.deviceAddress = vertices.address;
    g.geometry.triangles.vertexStride = 3 * sizeof(float);
    g.geometry.triangles.maxVertex = 2;
    g.geometry.triangles.indexType = VK_INDEX_TYPE_NONE_KHR;
    return g;
}

inline constexpr VkDeviceSize kTriangleBytes = 9 * sizeof(float);

// One identity instance of `bottom_level` (its device address), as VkAccelerationStructureInstanceKHR.
inline VkAccelerationStructureInstanceKHR identity_instance(VkDeviceAddress bottom_level) {
    VkAccelerationStructureInstanceKHR instance{};
    instance.transform.matrix[0][0] = instance.transform.matrix[1][1] =
        instance.transform.matrix[2][2] = 1.0f;
    instance.mask = 0xFF;
    instance.accelerationStructureReference = bottom_level;
    return instance;
}

// The geometry of a top level over the instances at `instances`.
inline VkAccelerationStructureGeometryKHR instance_geometry(const Buffer& instances) {
    VkAccelerationStructureGeometryKHR g{VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_GEOMETRY_KHR};
    g.geometryType = VK_GEOMETRY_TYPE_INSTANCES_KHR;
    g.geometry.instances.sType =
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_GEOMETRY_INSTANCES_DATA_KHR;
    g.geometry.instances.data.deviceAddress = instances.address;
    return g;
}

// Records the build of `s` over one primitive.
inline void cmd_build(const KhrCalls& khr, VkCommandBuffer cb, const Structure& s) {
    const VkAccelerationStructureBuildRangeInfoKHR one{1, 0, 0, 0};
    const VkAccelerationStructureBuildRangeInfoKHR* ranges = &one;
    khr.build(cb, 1, &s.build, &ranges);
}

inline KhrCalls load_khr(Gpu& gpu) {
    if (!gpu.khr_structures) unsupported(VK_KHR_ACCELERATION_STRUCTURE_EXTENSION_NAME);
    return KhrCalls{
        device_call<PFN_vkGetAccelerationStructureBuildSizesKHR>(
            gpu, "vkGetAccelerationStructureBuildSizesKHR"),
        device_call<PFN_vkCreateAccelerationStructureKHR>(gpu, "vkCreateAccelerationStructureKHR"),
        device_call<PFN_vkDestroyAccelerationStructureKHR>(gpu,
                                                           "vkDestroyAccelerationStructureKHR"),
        device_call<PFN_vkGetAccelerationStructureDeviceAddressKHR>(
            gpu, "vkGetAccelerationStructureDeviceAddressKHR"),
        device_call<PFN_vkCmdBuildAccelerationStructuresKHR>(
            gpu, "vkCmdBuildAccelerationStructuresKHR")};
}

}  // namespace bug_programs
