// SPDX-License-Identifier: Apache-2.0
// Traceable cluster BLASes (capture/README.md) end to end on lavapipe 25: served_scene.h's three
// triangle clusters built through the served extension, then one cluster BLAS over them with an
// explicit destination the application allocates from the served size answer, a KHR top level on
// the application's device whose one instance names that destination, and rays traced through it
// with trace_rays_khr (a ray-query compute shader). Prints one line per ray:
//   ray <i> hit <0|1> t <t> custom <c> instance <i> primitive <p> geometry <g> kind <k>
// for traceable_cluster_blas_test. With the argument `move`, the BLAS is moved (MOVE_OBJECTS,
// explicit destination) to a second buffer and its old home filled with 0xFF before the top
// level names the new address; `move-implicit` moves it so to an implicit destination;
// `move-indirect` to an explicit destination with every address of the move indirected
// (addressResolutionFlags: each field holds the address of a cell holding its value). With
// `implicit`, one command builds two cluster BLASes over the same clusters at implicit
// destinations (a region sized by the served implicit-mode answer) and the top level names the
// first (the one the second's driver BVH would overrun if the objects were packed by the engine's
// sizes); it prints both addresses. `implicit-indirect` does so with every address of the BLAS
// build indirected; `implicit-unaddressed` with no dstAddressesArray (the addresses printed are
// then dstImplicitData and the next object after the room dstSizesArray gives the first, as the
// served extension packs them). Exits 2 on a failed Vulkan call.
#include "cluster_test_device.h"
#include "served_scene.h"

#include "clastrace/capture/khr_ray_tracer.h"

#include <algorithm>
#include <cstdio>
#include <cstring>
#include <string>
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

// Where the BLAS ops of build_clusters_and_blas write: one explicit destination (`blas`, with
// `blas_size` bytes, the served size answer), or, where `implicit_ops` > 0, that many objects
// (all over the same clusters) packed into a region of `blas_size` bytes (the served answer for
// that many) at implicit destinations, whose addresses the build writes to `implicit_addresses`.
struct BlasDestinations {
    uint64_t blas = 0;
    uint32_t blas_size = 0;
    uint32_t implicit_ops = 0;
    bool indirect = false;     // every address of the BLAS build indirected
    bool unaddressed = false;  // implicit: no dstAddressesArray
    std::vector<uint64_t> implicit_addresses;
};

// Makes every address field of `command` indirected (addressResolutionFlags): the field then
// holds the address of an 8-byte cell holding its value, as an application that fills its
// address arrays on the GPU gives them.
void indirect_every_address(ClusterTestDevice& vk,
                            VkClusterAccelerationStructureCommandsInfoNV& command,
                            std::vector<Buffer>& keep) {
    auto cell = [&](VkDeviceAddress& field, uint32_t bit) {
        if (field == 0) return;
        keep.push_back(
            vk.makeBuffer(8, VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_BIT_KHR |
                                 VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_STORAGE_BIT_KHR));
        std::memcpy(keep.back().mapped, &field, 8);
        field = keep.back().address;
        command.addressResolutionFlags |= bit;
    };
    cell(command.srcInfosArray.deviceAddress,
         VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_SRC_INFOS_ARRAY_BIT_NV);
    cell(command.srcInfosCount,
         VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_SRC_INFOS_COUNT_BIT_NV);
    cell(command.dstAddressesArray.deviceAddress,
         VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_DST_ADDRESS_ARRAY_BIT_NV);
    cell(command.dstSizesArray.deviceAddress,
         VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_DST_SIZES_ARRAY_BIT_NV);
    cell(command.dstImplicitData,
         VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_DST_IMPLICIT_DATA_BIT_NV);
    cell(command.scratchData,
         VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_SCRATCH_DATA_BIT_NV);
}

// The clusters, then the BLAS, as served_scene.h builds them but with the BLAS destinations of
// `where`.
void build_clusters_and_blas(ClusterTestDevice& vk, BlasDestinations& where,
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
    const uint32_t ops = std::max(where.implicit_ops, 1u);
    constexpr uint64_t kBlasInfo =
        sizeof(VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV);
    a.blasInfos = make(kBlasInfo * ops, input).address;
    a.blasDstAddresses = make(8 * ops, storage).address;
    a.blasDstSizes = make(4 * ops, storage).address;
    a.blasScratch = make(1 << 20, 0).address;
    if (where.implicit_ops)  // clusterBottomLevelByteAlignment (256) inside the buffer
        a.blasImplicit = (make(where.blas_size + 256, storage).address + 255) / 256 * 256;
    served_scene::Inputs in = served_scene::makeInputs(a);
    in.counts[1] = ops;
    auto put = [&](size_t index, const void* data, size_t bytes) {
        std::memcpy(keep[first + index].mapped, data, bytes);
    };
    put(0, in.vertices.data(), in.vertices.size() * 4);
    put(1, in.indices.data(), in.indices.size() * 4);
    put(2, in.infos.data(), in.infos.size() * served_scene::kInfoStride);
    put(3, in.counts, sizeof in.counts);
    const std::vector<VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV> blasInfos(
        ops, in.blasInfo);  // every op over the same clusters
    put(8, blasInfos.data(), kBlasInfo * ops);
    served_scene::Commands commands;
    served_scene::makeCommands(a, commands);
    if (where.implicit_ops) {
        commands.blas.input.maxAccelerationStructureCount = ops;
        commands.bottomLevel.maxTotalClusterCount = served_scene::kMaxClusters * ops;
        commands.blas.srcInfosArray = {a.blasInfos, kBlasInfo, kBlasInfo * ops};
        commands.blas.dstAddressesArray.size = 8 * ops;
        commands.blas.dstSizesArray.size = 4 * ops;
    } else {
        put(9, &where.blas, 8);
        put(10, &where.blas_size, 4);  // explicit destinations: the room each has
        commands.blas.input.opMode =
            VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_EXPLICIT_DESTINATIONS_NV;
        commands.blas.dstImplicitData = 0;
    }
    if (where.unaddressed) commands.blas.dstAddressesArray = {0, 0, 0};
    if (where.indirect) indirect_every_address(vk, commands.blas, keep);

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
    where.implicit_addresses.resize(where.implicit_ops);
    if (where.implicit_ops && !where.unaddressed)
        std::memcpy(where.implicit_addresses.data(), keep[first + 9].mapped, 8 * ops);
    else if (where.implicit_ops) {  // packed from dstImplicitData, each after the room before
        uint64_t at = a.blasImplicit;
        for (uint32_t i = 0; i < ops; ++i) {
            where.implicit_addresses[i] = at;
            uint32_t room = 0;
            std::memcpy(&room, static_cast<const uint8_t*>(keep[first + 10].mapped) + 4 * i, 4);
            at = (at + room + 255) / 256 * 256;
        }
    }
}

// MOVE_OBJECTS of the cluster BLAS at `from` (`size` bytes, in `home` at `home_offset`) to the
// explicit destination `to` (0: an implicit destination, in a region the served answer sizes);
// then `from`'s bytes are filled with 0xFF, so rays through the destination, returned, can only
// hit what the move put there.
uint64_t move_blas(ClusterTestDevice& vk, uint64_t from, const Buffer& home,
                   VkDeviceSize home_offset, uint64_t to, uint32_t size, bool indirect,
                   std::vector<Buffer>& keep) {
    VkClusterAccelerationStructureMoveObjectsInputNV move{
        VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_MOVE_OBJECTS_INPUT_NV};
    move.type = VK_CLUSTER_ACCELERATION_STRUCTURE_TYPE_CLUSTERS_BOTTOM_LEVEL_NV;
    move.noMoveOverlap = VK_TRUE;
    move.maxMovedBytes = size;
    VkClusterAccelerationStructureCommandsInfoNV command{
        VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_COMMANDS_INFO_NV};
    command.input.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_INPUT_INFO_NV;
    command.input.maxAccelerationStructureCount = 1;
    command.input.opType = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV;
    command.input.opMode = to ? VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_EXPLICIT_DESTINATIONS_NV
                              : VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV;
    command.input.opInput.pMoveObjects = &move;
    VkAccelerationStructureBuildSizesInfoKHR sizes{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_BUILD_SIZES_INFO_KHR};
    vk.getBuildSizes(vk.device, &command.input, &sizes);
    const VkBufferUsageFlags input =
        VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_BIT_KHR;
    const VkBufferUsageFlags storage = VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_STORAGE_BIT_KHR;
    auto make = [&](VkDeviceSize bytes, VkBufferUsageFlags usage, const void* data) {
        keep.push_back(vk.makeBuffer(bytes, usage));
        if (data) std::memcpy(keep.back().mapped, data, bytes);
        return keep.back().address;
    };
    const uint32_t count = 1;
    const uint64_t src = make(8, input, &from), dst = make(8, storage, &to);
    const void* written_address = keep.back().mapped;  // dstAddressesArray[0]
    const uint64_t dst_size = make(4, storage, &size), counts = make(4, input, &count);
    command.scratchData = make(std::max<VkDeviceSize>(sizes.buildScratchSize, 256), 0, nullptr);
    command.srcInfosArray = {src, 8, 8};
    command.dstAddressesArray = {dst, 8, 8};
    command.dstSizesArray = {dst_size, 4, 4};
    command.srcInfosCount = counts;
    if (!to)  // clusterBottomLevelByteAlignment (256) inside the buffer
        command.dstImplicitData =
            (make(sizes.accelerationStructureSize + 256, storage, nullptr) + 255) / 256 * 256;
    if (indirect) indirect_every_address(vk, command, keep);
    VkCommandBuffer cb = vk.beginCommands();
    vk.cmdBuildClusters(cb, &command);
    VkMemoryBarrier barrier{VK_STRUCTURE_TYPE_MEMORY_BARRIER, nullptr,
                            VK_ACCESS_ACCELERATION_STRUCTURE_READ_BIT_KHR,
                            VK_ACCESS_TRANSFER_WRITE_BIT};
    vkCmdPipelineBarrier(cb, VK_PIPELINE_STAGE_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                         VK_PIPELINE_STAGE_TRANSFER_BIT, 0, 1, &barrier, 0, nullptr, 0, nullptr);
    vkCmdFillBuffer(cb, home.buffer, home_offset, size, 0xFFFFFFFFu);
    vk.submitAndWait(cb);
    if (!to) std::memcpy(&to, written_address, 8);  // where the implicit move put it
    return to;
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

// The implicit modes' build: two BLASes (`indirect`, `unaddressed`: BlasDestinations); returns the
// first one's address.
uint64_t build_implicit_blases(ClusterTestDevice& vk, bool indirect, bool unaddressed,
                               std::vector<Buffer>& keep) {
    served_scene::Commands sizing;
    served_scene::makeCommands({}, sizing);
    BlasDestinations where;
    where.implicit_ops = 2;
    where.indirect = indirect;
    where.unaddressed = unaddressed;
    sizing.blas.input.maxAccelerationStructureCount = where.implicit_ops;
    sizing.bottomLevel.maxTotalClusterCount = served_scene::kMaxClusters * where.implicit_ops;
    VkAccelerationStructureBuildSizesInfoKHR region{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_BUILD_SIZES_INFO_KHR};
    vk.getBuildSizes(vk.device, &sizing.blas.input, &region);
    where.blas_size = uint32_t(region.accelerationStructureSize);
    std::printf("implicit region %u\n", where.blas_size);
    build_clusters_and_blas(vk, where, keep);
    for (uint64_t address : where.implicit_addresses)
        std::printf("implicit blas at %llu\n", (unsigned long long)address);
    return where.implicit_addresses[0];
}

}  // namespace

int main(int argc, char** argv) {
    const bool moved = argc > 1 && std::strncmp(argv[1], "move", 4) == 0;
    const std::string mode = argc > 1 ? argv[1] : "";
    const bool moved_implicit = mode == "move-implicit";
    const bool implicit = mode.rfind("implicit", 0) == 0;
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
    uint64_t blas = 0;
    if (implicit) {
        blas = build_implicit_blases(vk, mode == "implicit-indirect",
                                     mode == "implicit-unaddressed", keep);
    } else {
        // clusterBottomLevelByteAlignment (256): the destination is aligned inside its buffer.
        keep.push_back(vk.makeBuffer(blasSize.accelerationStructureSize + 256,
                                     VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_STORAGE_BIT_KHR));
        BlasDestinations where;
        where.blas = (keep.back().address + 255) / 256 * 256;
        where.blas_size = uint32_t(blasSize.accelerationStructureSize);
        blas = where.blas;
        build_clusters_and_blas(vk, where, keep);
    }
    std::printf("blas at %llu\n", (unsigned long long)blas);
    uint64_t traced = blas;
    if (moved) {
        const Buffer home = keep.front();
        keep.push_back(vk.makeBuffer(blasSize.accelerationStructureSize + 256,
                                     VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_STORAGE_BIT_KHR));
        traced = moved_implicit ? 0 : (keep.back().address + 255) / 256 * 256;
        traced =
            move_blas(vk, blas, home, blas - home.address, traced,
                      uint32_t(blasSize.accelerationStructureSize), mode == "move-indirect", keep);
        std::printf("moved to %llu\n", (unsigned long long)traced);
    }
    const VkAccelerationStructureKHR tlas = build_top_level(vk, traced, keep);

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
