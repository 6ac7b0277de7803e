// SPDX-License-Identifier: Apache-2.0
// A headless program whose cluster structures live in a sparse buffer (VK_BUFFER_CREATE_
// SPARSE_BINDING_BIT) bound with vkQueueBindSparse, for the capture layer's end-to-end test on a
// driver with sparseBinding (lavapipe 25). The scene is served_scene.h's: triangle clusters
// built with implicit destinations, then a bottom level over the addresses that build wrote;
// dstImplicitData is the sparse buffer, so the bottom level also reads the clusters through it.
// The sparse buffer is bound whole to one allocation at a memory offset of one page.
//   bound OUT.json           the bind signals a semaphore the build's submission waits on
//   bind-after-use OUT.json  the bug: the builds are submitted (and waited for) before the
//                            sparse buffer is bound at all
// OUT.json: the sparse buffer (handle, address, size), its memory (handle, the bind's memory
// offset) and the bytes the builds left in every buffer (the sparse buffer's read through the
// memory bound under it). Exit 3 when the device lacks the extension or sparse binding.
#include "cluster_test_device.h"
#include "served_scene.h"

#include <clastrace/vk_cluster_abi.h>

#include <nlohmann/json.hpp>

#include <cstdio>
#include <cstring>
#include <fstream>

namespace {

using namespace clastrace::testapp;

struct Context : ClusterTestDevice {
    ~Context() { destroy(); }
};

// A sparse buffer and the one allocation bound under it (at `memoryOffset`).
struct SparseBuffer {
    VkBuffer buffer = VK_NULL_HANDLE;
    VkDeviceSize size = 0;
    VkDeviceAddress address = 0;
    VkDeviceMemory memory = VK_NULL_HANDLE;
    VkDeviceSize memoryOffset = 0;
    uint8_t* mapped = nullptr;  // the allocation's first byte

    void destroy(VkDevice device) {
        vkDestroyBuffer(device, buffer, nullptr);
        vkFreeMemory(device, memory, nullptr);
    }
};

SparseBuffer makeSparseBuffer(Context& c, VkDeviceSize atLeast) {
    SparseBuffer s;
    VkBufferCreateInfo info{};
    info.sType = VK_STRUCTURE_TYPE_BUFFER_CREATE_INFO;
    info.flags = VK_BUFFER_CREATE_SPARSE_BINDING_BIT;
    info.usage = VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_STORAGE_BIT_KHR |
                 VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_BIT_KHR |
                 VK_BUFFER_USAGE_STORAGE_BUFFER_BIT | VK_BUFFER_USAGE_SHADER_DEVICE_ADDRESS_BIT;
    info.size = atLeast;
    CHECK(vkCreateBuffer(c.device, &info, nullptr, &s.buffer));
    VkMemoryRequirements req;
    vkGetBufferMemoryRequirements(c.device, s.buffer, &req);
    // Whole pages, so that one bind of the buffer's size covers it (a bind may not reach past
    // the buffer's size, not even to the end of its last page).
    if (atLeast % req.alignment) {
        vkDestroyBuffer(c.device, s.buffer, nullptr);
        info.size = (atLeast / req.alignment + 1) * req.alignment;
        CHECK(vkCreateBuffer(c.device, &info, nullptr, &s.buffer));
        vkGetBufferMemoryRequirements(c.device, s.buffer, &req);
    }
    s.size = info.size;
    if (req.size != s.size) fail("the sparse buffer's memory size is not its size");
    s.memoryOffset = req.alignment;  // not at 0: the map must add the bind's memory offset
    VkPhysicalDeviceMemoryProperties props;
    vkGetPhysicalDeviceMemoryProperties(c.physicalDevice, &props);
    const VkMemoryPropertyFlags want =
        VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT | VK_MEMORY_PROPERTY_HOST_COHERENT_BIT;
    uint32_t type = 0;
    while (type < props.memoryTypeCount &&
           !((req.memoryTypeBits & (1u << type)) &&
             (props.memoryTypes[type].propertyFlags & want) == want))
        ++type;
    if (type == props.memoryTypeCount) fail("no host-visible coherent memory for sparse binds");
    VkMemoryAllocateFlagsInfo flags{VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_FLAGS_INFO, nullptr,
                                    VK_MEMORY_ALLOCATE_DEVICE_ADDRESS_BIT, 0};
    VkMemoryAllocateInfo alloc{VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_INFO, &flags,
                               s.memoryOffset + s.size, type};
    CHECK(vkAllocateMemory(c.device, &alloc, nullptr, &s.memory));
    void* mapped = nullptr;
    CHECK(vkMapMemory(c.device, s.memory, 0, VK_WHOLE_SIZE, 0, &mapped));
    s.mapped = static_cast<uint8_t*>(mapped);
    std::memset(s.mapped, 0xEE, s.memoryOffset + s.size);
    VkBufferDeviceAddressInfo addressInfo{VK_STRUCTURE_TYPE_BUFFER_DEVICE_ADDRESS_INFO, nullptr,
                                          s.buffer};
    s.address = vkGetBufferDeviceAddress(c.device, &addressInfo);
    return s;
}

// Binds the whole sparse buffer; signals `signal` when given.
void bindWhole(Context& c, const SparseBuffer& s, VkSemaphore signal) {
    VkSparseMemoryBind bind{0, s.size, s.memory, s.memoryOffset, 0};
    VkSparseBufferMemoryBindInfo bufferBind{s.buffer, 1, &bind};
    VkBindSparseInfo info{};
    info.sType = VK_STRUCTURE_TYPE_BIND_SPARSE_INFO;
    info.bufferBindCount = 1;
    info.pBufferBinds = &bufferBind;
    info.signalSemaphoreCount = signal ? 1 : 0;
    info.pSignalSemaphores = &signal;
    CHECK(vkQueueBindSparse(c.queue, 1, &info, VK_NULL_HANDLE));
}

// Submits `cb` waiting on `wait` (when given) and waits for it.
void submitWaitingOn(Context& c, VkCommandBuffer cb, VkSemaphore wait) {
    CHECK(vkEndCommandBuffer(cb));
    VkFenceCreateInfo fenceInfo{VK_STRUCTURE_TYPE_FENCE_CREATE_INFO, nullptr, 0};
    VkFence fence;
    CHECK(vkCreateFence(c.device, &fenceInfo, nullptr, &fence));
    const VkPipelineStageFlags stage = VK_PIPELINE_STAGE_ALL_COMMANDS_BIT;
    VkSubmitInfo submit{};
    submit.sType = VK_STRUCTURE_TYPE_SUBMIT_INFO;
    submit.waitSemaphoreCount = wait ? 1 : 0;
    submit.pWaitSemaphores = &wait;
    submit.pWaitDstStageMask = &stage;
    submit.commandBufferCount = 1;
    submit.pCommandBuffers = &cb;
    CHECK(vkQueueSubmit(c.queue, 1, &submit, fence));
    CHECK(vkWaitForFences(c.device, 1, &fence, VK_TRUE, 30ull * 1000 * 1000 * 1000));
    vkDestroyFence(c.device, fence, nullptr);
}

void recordBuilds(Context& c, VkCommandBuffer cb, const served_scene::Commands& commands) {
    c.cmdBuildClusters(cb, &commands.clusters);
    VkMemoryBarrier barrier{VK_STRUCTURE_TYPE_MEMORY_BARRIER, nullptr,
                            VK_ACCESS_ACCELERATION_STRUCTURE_WRITE_BIT_KHR,
                            VK_ACCESS_ACCELERATION_STRUCTURE_READ_BIT_KHR |
                                VK_ACCESS_SHADER_READ_BIT | VK_ACCESS_INDIRECT_COMMAND_READ_BIT};
    vkCmdPipelineBarrier(cb, VK_PIPELINE_STAGE_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                         VK_PIPELINE_STAGE_ACCELERATION_STRUCTURE_BUILD_BIT_KHR, 0, 1, &barrier, 0,
                         nullptr, 0, nullptr);
    c.cmdBuildClusters(cb, &commands.blas);
    VkMemoryBarrier toHost{VK_STRUCTURE_TYPE_MEMORY_BARRIER, nullptr,
                           VK_ACCESS_ACCELERATION_STRUCTURE_WRITE_BIT_KHR, VK_ACCESS_HOST_READ_BIT};
    vkCmdPipelineBarrier(cb, VK_PIPELINE_STAGE_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                         VK_PIPELINE_STAGE_HOST_BIT, 0, 1, &toHost, 0, nullptr, 0, nullptr);
}

bool hasSparseBinding(VkPhysicalDevice physicalDevice) {
    VkPhysicalDeviceFeatures features{};
    vkGetPhysicalDeviceFeatures(physicalDevice, &features);
    return features.sparseBinding == VK_TRUE;
}

int run(const char* outPath, bool bindFirst) {
    Context c;
    c.createInstance();
    if (!c.hasClusterExtension() || !hasSparseBinding(c.physicalDevice)) {
        std::printf("the device lacks VK_NV_cluster_acceleration_structure or sparseBinding\n");
        return 3;
    }
    c.sparseBinding = true;
    c.createDevice();

    served_scene::Commands sizing;
    served_scene::makeCommands({}, sizing);
    VkAccelerationStructureBuildSizesInfoKHR clusterSizes{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_BUILD_SIZES_INFO_KHR, nullptr, 0, 0, 0};
    VkAccelerationStructureBuildSizesInfoKHR blasSizes{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_BUILD_SIZES_INFO_KHR, nullptr, 0, 0, 0};
    c.getBuildSizes(c.device, &sizing.clusters.input, &clusterSizes);
    c.getBuildSizes(c.device, &sizing.blas.input, &blasSizes);

    const VkBufferUsageFlags input =
        VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_BIT_KHR;
    const VkBufferUsageFlags storage = VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_STORAGE_BIT_KHR;
    const served_scene::Inputs probe = served_scene::makeInputs({});
    Buffer vertices = c.makeBuffer(probe.vertices.size() * 4, input, 0xEE);
    Buffer indices = c.makeBuffer(probe.indices.size() * 4, input, 0xEE);
    Buffer infos =
        c.makeBuffer(served_scene::kInfoStride * served_scene::kMaxClusters, input, 0xEE);
    Buffer counts = c.makeBuffer(8, input, 0xEE);
    Buffer dstAddresses = c.makeBuffer(8 * served_scene::kMaxClusters, storage | input, 0xEE);
    Buffer dstSizes = c.makeBuffer(4 * served_scene::kMaxClusters, storage, 0xEE);
    SparseBuffer implicitData = makeSparseBuffer(c, clusterSizes.accelerationStructureSize);
    Buffer scratch = c.makeBuffer(clusterSizes.buildScratchSize, 0, 0xEE);
    Buffer blasInfos =
        c.makeBuffer(sizeof(VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV), input,
                     0xEE);
    Buffer blasDstAddresses = c.makeBuffer(8, storage, 0xEE);
    Buffer blasDstSizes = c.makeBuffer(4, storage, 0xEE);
    Buffer blasImplicit = c.makeBuffer(blasSizes.accelerationStructureSize, storage, 0xEE);
    Buffer blasScratch = c.makeBuffer(blasSizes.buildScratchSize, 0, 0xEE);

    const served_scene::Addresses a{vertices.address,     indices.address,
                                    infos.address,        counts.address,
                                    dstAddresses.address, dstSizes.address,
                                    implicitData.address, scratch.address,
                                    blasInfos.address,    blasDstAddresses.address,
                                    blasDstSizes.address, blasImplicit.address,
                                    blasScratch.address};
    const served_scene::Inputs in = served_scene::makeInputs(a);
    std::memcpy(vertices.mapped, in.vertices.data(), in.vertices.size() * 4);
    std::memcpy(indices.mapped, in.indices.data(), in.indices.size() * 4);
    std::memcpy(infos.mapped, in.infos.data(), in.infos.size() * served_scene::kInfoStride);
    std::memcpy(counts.mapped, in.counts, sizeof in.counts);
    std::memcpy(blasInfos.mapped, &in.blasInfo, sizeof in.blasInfo);
    served_scene::Commands commands;
    served_scene::makeCommands(a, commands);

    VkSemaphoreCreateInfo semaphoreInfo{VK_STRUCTURE_TYPE_SEMAPHORE_CREATE_INFO, nullptr, 0};
    VkSemaphore bound;
    CHECK(vkCreateSemaphore(c.device, &semaphoreInfo, nullptr, &bound));
    VkCommandBuffer cb = c.beginCommands();
    recordBuilds(c, cb, commands);
    if (bindFirst) {
        bindWhole(c, implicitData, bound);
        submitWaitingOn(c, cb, bound);
    } else {
        submitWaitingOn(c, cb, VK_NULL_HANDLE);  // the bug: nothing is bound under dstImplicitData
        bindWhole(c, implicitData, VK_NULL_HANDLE);
    }
    CHECK(vkQueueWaitIdle(c.queue));

    auto bufferJson = [](const Buffer& b) {
        return nlohmann::json{{"address", b.address},
                              {"size", b.size},
                              {"bytes", hex(b.mapped, b.size)}};
    };
    nlohmann::json out;
    out["sparse"] = {{"buffer", (uint64_t)implicitData.buffer},
                     {"address", implicitData.address},
                     {"size", implicitData.size},
                     {"memory", (uint64_t)implicitData.memory},
                     {"memoryOffset", implicitData.memoryOffset}};
    out["buffers"] = {{"vertices", bufferJson(vertices)},
                      {"indices", bufferJson(indices)},
                      {"infos", bufferJson(infos)},
                      {"counts", bufferJson(counts)},
                      {"dstAddresses", bufferJson(dstAddresses)},
                      {"dstSizes", bufferJson(dstSizes)},
                      {"implicitData",
                       {{"address", implicitData.address},
                        {"size", implicitData.size},
                        {"bytes",
                         hex(implicitData.mapped + implicitData.memoryOffset, implicitData.size)}}},
                      {"blasDstAddresses", bufferJson(blasDstAddresses)},
                      {"blasDstSizes", bufferJson(blasDstSizes)},
                      {"blasImplicit", bufferJson(blasImplicit)}};
    std::ofstream(outPath) << out.dump(1);
    vkDestroySemaphore(c.device, bound, nullptr);
    vkDeviceWaitIdle(c.device);
    implicitData.destroy(c.device);
    return 0;
}

}  // namespace

int main(int argc, char** argv) {
    if (argc == 3 && std::strcmp(argv[1], "bound") == 0) return run(argv[2], true);
    if (argc == 3 && std::strcmp(argv[1], "bind-after-use") == 0) return run(argv[2], false);
    std::fprintf(stderr, "usage: sparse_capture_app bound|bind-after-use OUT.json\n");
    return 1;
}
