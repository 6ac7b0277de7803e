// SPDX-License-Identifier: Apache-2.0
// Traceable cluster BLASes (capture/README.md) end to end on lavapipe 25: served_scene.h's three
// triangle clusters built through the served extension, then one cluster BLAS over them with an
// explicit destination the application allocates from the served size answer, a KHR top level on
// the application's device whose one instance names that destination, and rays traced through it
// with trace_rays_khr (a ray-query compute shader). Prints one line per ray:
//   ray <i> hit <0|1> t <t> custom <c> instance <i> primitive <p> geometry <g> kind <k>
// for traceable_cluster_blas_test. Exits 2 on a failed Vulkan call.
#include "cluster_test_device.h"
#include "served_scene.h"

#include "clastrace/capture/khr_ray_tracer.h"

#include <cstdio>
#include <cstring>
#include <vector>

using clastrace::testapp::Buffer;
using clastrace::testapp::ClusterTestDevice;

namespace {

template <class F>
F device_function(ClusterTestDevice& vk, const char* name) {
    auto f = (F)vkGetDeviceProcAddr(vk.device, name);
    if (!f) clastrace::testapp::fail(name);
    return f;
}

// The clusters, then the BLAS, as served_scene.h builds them but with an explicit BLAS
// destination: the object goes to address `blas`, `blas_size` bytes (the served size answer).
void build_clusters_and_blas(ClusterTestDevice& vk, uint64_t blas, uint32_t blas_size,
                             std::vector<Buffer>& keep) {
    const VkBufferUsageFlags input =
        VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_BIT_KHR;
    const VkBufferUsageFlags storage = VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_STORAGE_BIT_KHR;
    served_scene::Commands sizing;
    served_scene::makeCommands({}, sizing);
    VkAccelerationStructureBuildSizesInfoKHR clusterSizes{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_BUILD_SIZES_INFO_KHR};
    vk.getBuildSizes(vk.device, &sizing.clusters.input, &clusterSizes);
    const served_scene::Inputs probe = served_scene::makeInputs({});
    auto make = [&](VkDeviceSize size, VkBufferUsageFlags usage) -> const Buffer& {
        keep.push_back(vk.makeBuffer(size, usage));
        return keep.back();
    };
    keep.reserve(keep.size() + 16);
    const size_t first = keep.size();  // put() counts from the buffers made here
    served_scene::Addresses a;
    a.vertices = make(probe.vertices.size() * 4, input).address;
    a.indices = make(probe.indices.size() * 4, input).address;
    a.infos = make(served_scene::kInfoStride * served_scene::kMaxClusters, input).address;
    a.counts = make(8, input).address;
    a.dstAddresses = make(8 * served_scene::kMaxClusters, storage | input).address;
    a.dstSizes = make(4 * served_scene::kMaxClusters, storage).address;
    a.implicitData = make(clusterSizes.accelerationStructureSize, storage).address;
    a.scratch = make(clusterSizes.buildScratchSize, 0).address;
    a.blasInfos =
        make(sizeof(VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV), input).address;
    a.blasDstAddresses = make(8, storage).address;
    a.blasDstSizes = make(4, storage).address;
    a.blasScratch = make(1 << 20, 0).address;
    const served_scene::Inputs in = served_scene::makeInputs(a);
    auto put = [&](size_t index, const void* data, size_t bytes) {
        std::memcpy(keep[first + index].mapped, data, bytes);
    };
    put(0, in.vertices.data(), in.vertices.size() * 4);
    put(1, in.indices.data(), in.indices.size() * 4);
    put(2, in.infos.data(), in.infos.size() * served_scene::kInfoStride);
    put(3, in.counts, sizeof in.counts);
    put(8, &in.blasInfo, sizeof in.blasInfo);
    put(9, &blas, 8);
    put(10, &blas_size, 4);  // explicit destinations: the room each has
    served_scene::Commands commands;
    served_scene::makeCommands(a, commands);
    commands.blas.input.opMode = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_EXPLICIT_DESTINATIONS_NV;
    commands.blas.dstImplicitData = 0;

    VkCommandBuffer cb = vk.beginCommands();
    vk.cmdBuildClusters(cb, &commands.clusters);
    VkMemoryBarrier barrier{VK_STRUCTURE_TYPE_MEMORY_BARRIER, nullptr,
                            VK_ACCESS_ACCELERATION_STRUCTURE_WRITE_BIT_KHR,
                            VK_ACCESS_ACCELERATION_STRUCTURE_READ_BIT_KHR |
                                VK_ACCESS_SHADER_READ_BIT | VK_ACCESS_INDIRECT_COMMAND_READ_BIT};
    vkCmdPipelineBarrier(cb, VK_PIPELINE_STAGE_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                         VK_PIPELINE_STAGE_ACCELERATION_STRUCTURE_BUILD_BIT_KHR, 0, 1, &barrier, 0,
                         nullptr, 0, nullptr);
    vk.cmdBuildClusters(cb, &commands.blas);
    vk.submitAndWait(cb);
}

// A top level of one instance (custom index 7) naming `blas_address`, built and waited for.
VkAccelerationStructureKHR build_top_level(ClusterTestDevice& vk, uint64_t blas_address,
                                           std::vector<Buffer>& keep) {
    VkAccelerationStructureInstanceKHR instance{};
    instance.transform = {{{1, 0, 0, 0}, {0, 1, 0, 0}, {0, 0, 1, 0}}};
    instance.instanceCustomIndex = 7;
    instance.mask = 0xFF;
    instance.accelerationStructureReference = blas_address;
    keep.push_back(
        vk.makeBuffer(sizeof instance,
                      VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_BIT_KHR));
    std::memcpy(keep.back().mapped, &instance, sizeof instance);
    VkAccelerationStructureGeometryKHR top{VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_GEOMETRY_KHR};
    top.geometryType = VK_GEOMETRY_TYPE_INSTANCES_KHR;
    top.geometry.instances.sType =
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_GEOMETRY_INSTANCES_DATA_KHR;
    top.geometry.instances.data.deviceAddress = keep.back().address;
    VkAccelerationStructureBuildGeometryInfoKHR info{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_BUILD_GEOMETRY_INFO_KHR};
    info.type = VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_KHR;
    info.mode = VK_BUILD_ACCELERATION_STRUCTURE_MODE_BUILD_KHR;
    info.geometryCount = 1;
    info.pGeometries = &top;
    const uint32_t count = 1;
    VkAccelerationStructureBuildSizesInfoKHR size{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_BUILD_SIZES_INFO_KHR};
    device_function<PFN_vkGetAccelerationStructureBuildSizesKHR>(
        vk,
        "vkGetAccelerationStructureBuildSizesKHR")(vk.device,
                                                   VK_ACCELERATION_STRUCTURE_BUILD_TYPE_DEVICE_KHR,
                                                   &info, &count, &size);
    keep.push_back(vk.makeBuffer(size.accelerationStructureSize,
                                 VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_STORAGE_BIT_KHR));
    VkAccelerationStructureCreateInfoKHR create{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_CREATE_INFO_KHR};
    create.buffer = keep.back().buffer;
    create.size = size.accelerationStructureSize;
    create.type = VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_KHR;
    VkAccelerationStructureKHR tlas;
    CHECK(device_function<PFN_vkCreateAccelerationStructureKHR>(
        vk, "vkCreateAccelerationStructureKHR")(vk.device, &create, nullptr, &tlas));
    keep.push_back(vk.makeBuffer(size.buildScratchSize, 0));
    info.dstAccelerationStructure = tlas;
    info.scratchData.deviceAddress = keep.back().address;
    const VkAccelerationStructureBuildRangeInfoKHR range{1, 0, 0, 0};
    const VkAccelerationStructureBuildRangeInfoKHR* ranges = &range;
    VkCommandBuffer cb = vk.beginCommands();
    device_function<PFN_vkCmdBuildAccelerationStructuresKHR>(
        vk, "vkCmdBuildAccelerationStructuresKHR")(cb, 1, &info, &ranges);
    vk.submitAndWait(cb);
    return tlas;
}

}  // namespace

int main() {
    ClusterTestDevice vk;
    vk.rayTracing = true;
    vk.createInstance();
    vk.createDevice();
    served_scene::Commands sizing;
    served_scene::makeCommands({}, sizing);
    sizing.blas.input.opMode = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_EXPLICIT_DESTINATIONS_NV;
    VkAccelerationStructureBuildSizesInfoKHR blasSize{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_BUILD_SIZES_INFO_KHR};
    vk.getBuildSizes(vk.device, &sizing.blas.input, &blasSize);
    std::printf("blas size %llu\n", (unsigned long long)blasSize.accelerationStructureSize);
    std::vector<Buffer> keep;
    // clusterBottomLevelByteAlignment (256): the destination is aligned inside its buffer.
    keep.push_back(vk.makeBuffer(blasSize.accelerationStructureSize + 256,
                                 VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_STORAGE_BIT_KHR));
    const uint64_t blas = (keep.back().address + 255) / 256 * 256;
    std::printf("blas at %llu\n", (unsigned long long)blas);
    build_clusters_and_blas(vk, blas, uint32_t(blasSize.accelerationStructureSize), keep);
    const VkAccelerationStructureKHR tlas = build_top_level(vk, blas, keep);

    // One geometry slot per cluster reference (served_scene::kClusterCount of them).
    clastrace::capture::NvTraceScene scene;
    scene.instances = {{0, 0}};
    scene.geometry_is_aabb.assign(served_scene::kClusterCount, 0);
    scene.geometry_first_box.assign(served_scene::kClusterCount, 0);
    // Cluster c spans x in [10c, 10c + 0.5 (c + 1)], y in [0, 0.25 (c + 2)] at z = c: rays
    // straight down over each, from both halves of a quad, and one between the clusters.
    std::vector<clastrace::capture::NvTracedRay> rays;
    for (uint32_t c = 0; c < served_scene::kClusterCount; ++c)
        for (float dx : {0.05f, 0.2f, 0.45f})
            for (float dy : {0.03f, 0.2f})
                rays.push_back({{10.0f * float(c) + dx, dy, 10}, 0, {0, 0, -1}, 100, 0, 0xFF, {}});
    rays.push_back({{5, 0.1f, 10}, 0, {0, 0, -1}, 100, 0, 0xFF, {}});  // between: a miss
    clastrace::capture::NvRayTracerContext context;
    context.device = vk.device;
    context.queue = vk.queue;
    context.queue_family_index = vk.queueFamily;
    context.get_device_proc_addr = vkGetDeviceProcAddr;
    vkGetPhysicalDeviceMemoryProperties(vk.physicalDevice, &context.memory_properties);
    std::vector<clastrace::capture::NvRayHit> hits;
    std::string error;
    if (!clastrace::capture::trace_rays_khr(context, tlas, scene, rays, hits, error)) {
        std::fprintf(stderr, "traceable_cluster_app: trace_rays_khr failed: %s\n", error.c_str());
        return 2;
    }
    for (size_t i = 0; i < hits.size(); ++i) {
        const auto& h = hits[i];
        std::printf(
            "ray %zu hit %u t %.6g custom %u instance %u primitive %u geometry %u kind %u\n", i,
            h.hit, double(h.t), h.instance_custom_index, h.instance_id, h.primitive_id,
            h.geometry_index, h.hit_kind);
    }
    device_function<PFN_vkDestroyAccelerationStructureKHR>(vk, "vkDestroyAccelerationStructureKHR")(
        vk.device, tlas, nullptr);
    vk.destroy();
    return 0;
}
