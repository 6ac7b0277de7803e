// SPDX-License-Identifier: Apache-2.0
// The engine sub-allocates transient buffers from one memory block. Bug: after submitting the
// cluster build, it retires the vertex buffer at once (no fence wait), binds a new buffer to
// the same bytes of the block and clears it in the next submission, which nothing orders after
// the build: the clear may overwrite vertices the build is still reading. --destroy-only
// retires the buffer as early but reuses nothing. --fixed waits on the build's fence before
// retiring the buffer.
#include "bug_gpu.h"

using namespace bug_programs;

namespace {

struct Block {
    VkDeviceMemory memory = VK_NULL_HANDLE;
    unsigned char* host = nullptr;
};

Block allocate_block(Gpu& gpu, const Buffer& like, VkDeviceSize size) {
    VkMemoryAllocateFlagsInfo flags{VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_FLAGS_INFO};
    flags.flags = VK_MEMORY_ALLOCATE_DEVICE_ADDRESS_BIT;
    VkMemoryAllocateInfo alloc{VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_INFO, &flags};
    alloc.allocationSize = size;
    // The memory type the helper's buffers use: look it up through one of them.
    VkMemoryRequirements need;
    vkGetBufferMemoryRequirements(gpu.device, like.buffer, &need);
    VkPhysicalDeviceMemoryProperties memory;
    vkGetPhysicalDeviceMemoryProperties(gpu.physical, &memory);
    const VkMemoryPropertyFlags want =
        VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT | VK_MEMORY_PROPERTY_HOST_COHERENT_BIT;
    for (uint32_t i = 0; i < memory.memoryTypeCount; ++i)
        if ((need.memoryTypeBits & (1u << i)) &&
            (memory.memoryTypes[i].propertyFlags & want) == want) {
            alloc.memoryTypeIndex = i;
            break;
        }
    Block block;
    vk_ok(vkAllocateMemory(gpu.device, &alloc, nullptr, &block.memory), "vkAllocateMemory");
    void* mapped = nullptr;
    vk_ok(vkMapMemory(gpu.device, block.memory, 0, VK_WHOLE_SIZE, 0, &mapped), "vkMapMemory");
    block.host = static_cast<unsigned char*>(mapped);
    return block;
}

// A buffer over the first `size` bytes of `block`.
Buffer place(Gpu& gpu, const Block& block, VkDeviceSize size) {
    Buffer b;
    b.size = size;
    b.memory = block.memory;
    b.host = block.host;
    VkBufferCreateInfo info{VK_STRUCTURE_TYPE_BUFFER_CREATE_INFO};
    info.size = size;
    info.usage = VK_BUFFER_USAGE_SHADER_DEVICE_ADDRESS_BIT | VK_BUFFER_USAGE_TRANSFER_DST_BIT |
                 VK_BUFFER_USAGE_STORAGE_BUFFER_BIT |
                 VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_BIT_KHR;
    vk_ok(vkCreateBuffer(gpu.device, &info, nullptr, &b.buffer), "vkCreateBuffer");
    vk_ok(vkBindBufferMemory(gpu.device, b.buffer, block.memory, 0), "vkBindBufferMemory");
    VkBufferDeviceAddressInfo where{VK_STRUCTURE_TYPE_BUFFER_DEVICE_ADDRESS_INFO, nullptr,
                                    b.buffer};
    b.address = vkGetBufferDeviceAddress(gpu.device, &where);
    return b;
}

}  // namespace

int main(int argc, char** argv) {
    const bool fixed = has_flag(argc, argv, "--fixed");
    const bool destroy_only = has_flag(argc, argv, "--destroy-only");
    Gpu gpu;
    open(gpu, "input_memory_reused");
    Quads quads = make_quads(gpu, 4);
    const Block block = allocate_block(gpu, quads.vertices, 1 << 16);
    Buffer vertices = place(gpu, block, quads.vertices.size);
    std::memcpy(vertices.host, quads.vertices.host, quads.vertices.size);
    quads.vertices = vertices;
    ClasBuild clas;
    prepare_clas_build(gpu, quads, clas);

    VkCommandBuffer build = gpu.begin();
    gpu.cmd_build_clusters(build, &clas.info);
    VkFence built = gpu.fence();
    gpu.submit(build, built);
    if (fixed) gpu.wait(built);
    vkDestroyBuffer(gpu.device, vertices.buffer, nullptr);  // retired: its bytes go back

    if (!destroy_only) {
        Buffer transient = place(gpu, block, quads.vertices.size);
        VkCommandBuffer next = gpu.begin();
        vkCmdFillBuffer(next, transient.buffer, 0, VK_WHOLE_SIZE, 0);
        gpu.submit_and_wait(next);
        vkDestroyBuffer(gpu.device, transient.buffer, nullptr);
    }
    if (!fixed) gpu.wait(built);
    print_range("vertices", vertices.address, vertices.size);
    vkFreeMemory(gpu.device, block.memory, nullptr);
    return 0;
}
