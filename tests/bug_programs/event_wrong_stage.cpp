// SPDX-License-Identifier: Apache-2.0
// Bug: the src infos are copied in (vkCmdCopyBuffer), and an event orders the cluster build
// after them, but the event's dependency names COMPUTE_SHADER/SHADER_WRITE as its source, so
// the copy's writes are outside its first scope. --fixed names COPY/TRANSFER_WRITE.
#include "bug_gpu.h"

using namespace bug_programs;

int main(int argc, char** argv) {
    const bool fixed = has_flag(argc, argv, "--fixed");
    Gpu gpu;
    open(gpu, "event_wrong_stage");
    const Quads quads = make_quads(gpu, 3);
    ClasBuild clas;
    prepare_clas_build(gpu, quads, clas);
    Buffer staging = gpu.buffer(clas.infos.size);
    std::memcpy(staging.host, clas.infos.host, clas.infos.size);
    std::memset(clas.infos.host, 0, clas.infos.size);
    VkEventCreateInfo event_info{VK_STRUCTURE_TYPE_EVENT_CREATE_INFO};
    event_info.flags = VK_EVENT_CREATE_DEVICE_ONLY_BIT;
    VkEvent copied = VK_NULL_HANDLE;
    vk_ok(vkCreateEvent(gpu.device, &event_info, nullptr, &copied), "vkCreateEvent");

    VkMemoryBarrier2 barrier{VK_STRUCTURE_TYPE_MEMORY_BARRIER_2};
    barrier.srcStageMask =
        fixed ? VK_PIPELINE_STAGE_2_COPY_BIT : VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT;
    barrier.srcAccessMask = fixed ? VK_ACCESS_2_TRANSFER_WRITE_BIT : VK_ACCESS_2_SHADER_WRITE_BIT;
    barrier.dstStageMask = VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR;
    barrier.dstAccessMask = VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT;
    VkDependencyInfo dependency{VK_STRUCTURE_TYPE_DEPENDENCY_INFO};
    dependency.memoryBarrierCount = 1;
    dependency.pMemoryBarriers = &barrier;

    VkCommandBuffer cb = gpu.begin();
    const VkBufferCopy whole{0, 0, clas.infos.size};
    vkCmdCopyBuffer(cb, staging.buffer, clas.infos.buffer, 1, &whole);
    vkCmdSetEvent2(cb, copied, &dependency);
    vkCmdWaitEvents2(cb, 1, &copied, &dependency);
    gpu.cmd_build_clusters(cb, &clas.info);
    gpu.submit_and_wait(cb);
    print_range("infos", clas.infos.address, clas.infos.size);
    vkDestroyEvent(gpu.device, copied, nullptr);
    return 0;
}
