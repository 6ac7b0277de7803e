// SPDX-License-Identifier: Apache-2.0
// The ray check's KHR tracer (capture/include/clastrace/capture/khr_ray_tracer.h) on a real
// driver with ray queries (lavapipe 25): builds a small KHR scene through the loader — a bottom
// level of two triangle geometries (a quad at z = 0 of two triangles, one triangle at z = -2)
// and one of a single box, instanced twice (the box scaled 2x and moved to x = 5, mask 0x02) —
// traces fixed rays with trace_rays_khr, and prints one line per ray:
//   ray <i> hit <0|1> t <t> custom <c> instance <i> primitive <p> geometry <g> kind <k> u <u> v <v>
// for khr_ray_tracer_test to check. Exits 2 on a failed Vulkan call.
#include "cluster_test_device.h"

#include "clastrace/capture/khr_ray_tracer.h"

#include <cstdio>
#include <cstring>
#include <vector>

using clastrace::testapp::Buffer;
using clastrace::testapp::ClusterTestDevice;

namespace {

// SPIR-V ray flags (gl_RayFlagsCullBackFacingTrianglesEXT, ...FrontFacing...).
constexpr uint32_t kCullBackFacing = 0x10;
constexpr uint32_t kCullFrontFacing = 0x20;

struct Builder {
    ClusterTestDevice& vk;
    PFN_vkGetAccelerationStructureBuildSizesKHR sizes = nullptr;
    PFN_vkCreateAccelerationStructureKHR create = nullptr;
    PFN_vkCmdBuildAccelerationStructuresKHR build = nullptr;
    PFN_vkGetAccelerationStructureDeviceAddressKHR address = nullptr;

    explicit Builder(ClusterTestDevice& d) : vk(d) {
        sizes = (PFN_vkGetAccelerationStructureBuildSizesKHR)
            vkGetDeviceProcAddr(vk.device, "vkGetAccelerationStructureBuildSizesKHR");
        create = (PFN_vkCreateAccelerationStructureKHR)
            vkGetDeviceProcAddr(vk.device, "vkCreateAccelerationStructureKHR");
        build = (PFN_vkCmdBuildAccelerationStructuresKHR)
            vkGetDeviceProcAddr(vk.device, "vkCmdBuildAccelerationStructuresKHR");
        address = (PFN_vkGetAccelerationStructureDeviceAddressKHR)
            vkGetDeviceProcAddr(vk.device, "vkGetAccelerationStructureDeviceAddressKHR");
        if (!sizes || !create || !build || !address)
            clastrace::testapp::fail("the VK_KHR_acceleration_structure entry points are missing");
    }

    // Builds one structure from `geometries` (one range each, `counts` primitives) and waits.
    VkAccelerationStructureKHR make(
        VkAccelerationStructureTypeKHR type,
        const std::vector<VkAccelerationStructureGeometryKHR>& geometries,
        const std::vector<uint32_t>& counts) {
        VkAccelerationStructureBuildGeometryInfoKHR info{
            VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_BUILD_GEOMETRY_INFO_KHR};
        info.type = type;
        info.mode = VK_BUILD_ACCELERATION_STRUCTURE_MODE_BUILD_KHR;
        info.geometryCount = uint32_t(geometries.size());
        info.pGeometries = geometries.data();
        VkAccelerationStructureBuildSizesInfoKHR size{
            VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_BUILD_SIZES_INFO_KHR};
        sizes(vk.device, VK_ACCELERATION_STRUCTURE_BUILD_TYPE_DEVICE_KHR, &info, counts.data(),
              &size);
        const Buffer storage =
            vk.makeBuffer(size.accelerationStructureSize,
                          VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_STORAGE_BIT_KHR);
        const Buffer scratch = vk.makeBuffer(size.buildScratchSize, 0);
        VkAccelerationStructureCreateInfoKHR createInfo{
            VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_CREATE_INFO_KHR};
        createInfo.buffer = storage.buffer;
        createInfo.size = size.accelerationStructureSize;
        createInfo.type = type;
        VkAccelerationStructureKHR out;
        CHECK(create(vk.device, &createInfo, nullptr, &out));
        info.dstAccelerationStructure = out;
        info.scratchData.deviceAddress = scratch.address;
        std::vector<VkAccelerationStructureBuildRangeInfoKHR> ranges;
        for (uint32_t c : counts) ranges.push_back({c, 0, 0, 0});
        const VkAccelerationStructureBuildRangeInfoKHR* rows = ranges.data();
        VkCommandBuffer cb = vk.beginCommands();
        build(cb, 1, &info, &rows);
        vk.submitAndWait(cb);
        return out;
    }

    VkDeviceAddress address_of(VkAccelerationStructureKHR s) const {
        VkAccelerationStructureDeviceAddressInfoKHR info{
            VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_DEVICE_ADDRESS_INFO_KHR, nullptr, s};
        return address(vk.device, &info);
    }
};

Buffer upload(ClusterTestDevice& vk, const void* data, size_t bytes) {
    Buffer b =
        vk.makeBuffer(bytes, VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_BIT_KHR);
    std::memcpy(b.mapped, data, bytes);
    return b;
}

VkAccelerationStructureGeometryKHR triangles(const Buffer& vertices, const Buffer& indices,
                                             uint32_t max_vertex) {
    VkAccelerationStructureGeometryKHR g{VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_GEOMETRY_KHR};
    g.geometryType = VK_GEOMETRY_TYPE_TRIANGLES_KHR;
    g.flags = VK_GEOMETRY_OPAQUE_BIT_KHR;
    auto& t = g.geometry.triangles;
    t.sType = VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_GEOMETRY_TRIANGLES_DATA_KHR;
    t.vertexFormat = VK_FORMAT_R32G32B32_SFLOAT;
    t.vertexData.deviceAddress = vertices.address;
    t.vertexStride = 12;
    t.maxVertex = max_vertex;
    t.indexType = VK_INDEX_TYPE_UINT32;
    t.indexData.deviceAddress = indices.address;
    return g;
}

}  // namespace

int main() {
    ClusterTestDevice vk;
    vk.clusters = false;
    vk.rayTracing = true;
    vk.createInstance();
    vk.createDevice();
    Builder b(vk);

    const float quad[] = {-1, -1, 0, 1, -1, 0, 1, 1, 0, -1, 1, 0};
    const uint32_t quad_indices[] = {0, 1, 2, 0, 2, 3};
    const float lower[] = {-1, -1, -2, 1, -1, -2, 0, 1, -2};
    const uint32_t lower_indices[] = {0, 1, 2};
    const float box[] = {-0.5f, -0.5f, -0.5f, 0.5f, 0.5f, 0.5f};
    const Buffer quad_vertices = upload(vk, quad, sizeof quad);
    const Buffer quad_index_buffer = upload(vk, quad_indices, sizeof quad_indices);
    const Buffer lower_vertices = upload(vk, lower, sizeof lower);
    const Buffer lower_index_buffer = upload(vk, lower_indices, sizeof lower_indices);
    const Buffer boxes = upload(vk, box, sizeof box);

    const VkAccelerationStructureKHR mesh =
        b.make(VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR,
               {triangles(quad_vertices, quad_index_buffer, 3),
                triangles(lower_vertices, lower_index_buffer, 2)},
               {2, 1});
    VkAccelerationStructureGeometryKHR aabbs{VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_GEOMETRY_KHR};
    aabbs.geometryType = VK_GEOMETRY_TYPE_AABBS_KHR;
    aabbs.geometry.aabbs.sType = VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_GEOMETRY_AABBS_DATA_KHR;
    aabbs.geometry.aabbs.data.deviceAddress = boxes.address;
    aabbs.geometry.aabbs.stride = sizeof box;
    const VkAccelerationStructureKHR procedural =
        b.make(VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR, {aabbs}, {1});

    VkAccelerationStructureInstanceKHR instances[2] = {};
    instances[0].transform = {{{1, 0, 0, 0}, {0, 1, 0, 0}, {0, 0, 1, 0}}};
    instances[0].instanceCustomIndex = 7;
    instances[0].mask = 0xFF;
    instances[0].accelerationStructureReference = b.address_of(mesh);
    instances[1].transform = {{{2, 0, 0, 5}, {0, 2, 0, 0}, {0, 0, 2, 0}}};
    instances[1].instanceCustomIndex = 9;
    instances[1].mask = 0x02;
    instances[1].accelerationStructureReference = b.address_of(procedural);
    const Buffer instance_buffer = upload(vk, instances, sizeof instances);
    VkAccelerationStructureGeometryKHR top{VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_GEOMETRY_KHR};
    top.geometryType = VK_GEOMETRY_TYPE_INSTANCES_KHR;
    top.geometry.instances.sType =
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_GEOMETRY_INSTANCES_DATA_KHR;
    top.geometry.instances.data.deviceAddress = instance_buffer.address;
    const VkAccelerationStructureKHR tlas =
        b.make(VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_KHR, {top}, {2});

    // Instance 0's bottom level has geometry slots 0 and 1 (triangles), instance 1's slot 2 (box 0).
    clastrace::capture::NvTraceScene scene;
    scene.instances = {{0, 0}, {0, 2}};
    scene.geometry_is_aabb = {0, 0, 1};
    scene.geometry_first_box = {0, 0, 0};
    scene.boxes.assign(box, box + 6);
    using clastrace::capture::NvTracedRay;
    auto ray = [](float ox, float oy, float oz, float tmin, float dx, float dy, float dz,
                  float tmax, uint32_t flags, uint32_t mask) {
        return NvTracedRay{{ox, oy, oz}, tmin, {dx, dy, dz}, tmax, flags, mask, {0, 0}};
    };
    const std::vector<NvTracedRay> rays = {
        ray(0.25f, 0.5f, 5, 0, 0, 0, -1, 100, 0, 0xFF),  // 0: quad, triangle 1, t 5
        ray(0.5f, 0.25f, 5, 0, 0, 0, -1, 100, 0, 0xFF),  // 1: quad, triangle 0
        ray(0, 0, -5, 0, 0, 0, 1, 100, 0, 0xFF),         // 2: from below: geometry 1, t 3
        ray(5, 0, 5, 0, 0, 0, -1, 100, 0, 0xFF),         // 3: the scaled box, t 4
        ray(5, 0, 5, 0, 0, 0, -1, 100, 0, 0x01),         // 4: masked out: miss
        ray(0.25f, 0.5f, 5, 0, 0, 0, -1, 4, 0, 0xFF),    // 5: t_max short of the quad
        ray(20, 20, 20, 0, 1, 0, 0, 100, 0, 0xFF),       // 6: nothing there
        ray(0.25f, 0.5f, 5, 0, 0, 0, -1, 100, kCullFrontFacing,
            0xFF),  // 7
        ray(0.25f, 0.5f, 5, 0, 0, 0, -1, 100, kCullBackFacing,
            0xFF),                               // 8: one of 7, 8 hits
        ray(5, 0, 0, 0, 0, 0, 1, 100, 0, 0xFF),  // 9: inside the box: t = t_min = 0
    };
    clastrace::capture::NvRayTracerContext context;
    context.device = vk.device;
    context.queue = vk.queue;
    context.queue_family_index = vk.queueFamily;
    context.get_device_proc_addr = vkGetDeviceProcAddr;
    vkGetPhysicalDeviceMemoryProperties(vk.physicalDevice, &context.memory_properties);
    std::vector<clastrace::capture::NvRayHit> hits;
    std::string error;
    if (!clastrace::capture::trace_rays_khr(context, tlas, scene, rays, hits, error)) {
        std::fprintf(stderr, "khr_ray_query_app: trace_rays_khr failed: %s\n", error.c_str());
        return 2;
    }
    for (size_t i = 0; i < hits.size(); ++i) {
        const auto& h = hits[i];
        std::printf(
            "ray %zu hit %u t %.6g custom %u instance %u primitive %u geometry %u kind %u "
            "u %.6g v %.6g\n",
            i, h.hit, double(h.t), h.instance_custom_index, h.instance_id, h.primitive_id,
            h.geometry_index, h.hit_kind, double(h.u), double(h.v));
    }
    auto destroy_structure = (PFN_vkDestroyAccelerationStructureKHR)
        vkGetDeviceProcAddr(vk.device, "vkDestroyAccelerationStructureKHR");
    for (VkAccelerationStructureKHR s : {tlas, procedural, mesh})
        destroy_structure(vk.device, s, nullptr);
    vk.destroy();
    return 0;
}
