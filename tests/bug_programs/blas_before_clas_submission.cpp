// SPDX-License-Identifier: Apache-2.0
// Bug: the engine records the cluster build and the bottom level over it in two command
// buffers, but submits them in the wrong order: the bottom level's submission goes first and
// reads the CLAS addresses (dstAddressesArray, still zero) before the cluster build, in the
// next submission, writes them; nothing orders the two either way. --fixed submits the
// cluster build first and has the bottom level wait on a semaphore it signals.
#include "bug_gpu.h"

using namespace bug_programs;

int main(int argc, char** argv) {
    const bool fixed = has_flag(argc, argv, "--fixed");
    Gpu gpu;
    open(gpu, "blas_before_clas_submission");
    const Quads quads = make_quads(gpu, 3);
    ClasBuild clas;
    prepare_clas_build(gpu, quads, clas);
    BlasBuild blas;
    prepare_blas_build(gpu, clas, quads.count, blas);
    VkSemaphoreCreateInfo semaphore_info{VK_STRUCTURE_TYPE_SEMAPHORE_CREATE_INFO};
    VkSemaphore clusters_done = VK_NULL_HANDLE;
    vk_ok(vkCreateSemaphore(gpu.device, &semaphore_info, nullptr, &clusters_done),
          "vkCreateSemaphore");

    VkCommandBuffer clusters = gpu.begin();
    gpu.cmd_build_clusters(clusters, &clas.info);
    vk_ok(vkEndCommandBuffer(clusters), "vkEndCommandBuffer");
    VkCommandBuffer bottom = gpu.begin();
    gpu.cmd_build_clusters(bottom, &blas.info);
    vk_ok(vkEndCommandBuffer(bottom), "vkEndCommandBuffer");

    VkCommandBufferSubmitInfo commands[2] = {{VK_STRUCTURE_TYPE_COMMAND_BUFFER_SUBMIT_INFO},
                                             {VK_STRUCTURE_TYPE_COMMAND_BUFFER_SUBMIT_INFO}};
    commands[0].commandBuffer = fixed ? clusters : bottom;
    commands[1].commandBuffer = fixed ? bottom : clusters;
    VkSemaphoreSubmitInfo signal{VK_STRUCTURE_TYPE_SEMAPHORE_SUBMIT_INFO};
    signal.semaphore = clusters_done;
    signal.stageMask = VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR;
    VkSubmitInfo2 submits[2] = {{VK_STRUCTURE_TYPE_SUBMIT_INFO_2},
                                {VK_STRUCTURE_TYPE_SUBMIT_INFO_2}};
    for (int i = 0; i < 2; ++i) {
        submits[i].commandBufferInfoCount = 1;
        submits[i].pCommandBufferInfos = &commands[i];
    }
    if (fixed) {
        submits[0].signalSemaphoreInfoCount = 1;
        submits[0].pSignalSemaphoreInfos = &signal;
        submits[1].waitSemaphoreInfoCount = 1;
        submits[1].pWaitSemaphoreInfos = &signal;
    }
    vk_ok(vkQueueSubmit2(gpu.queue, 1, &submits[0], VK_NULL_HANDLE), "vkQueueSubmit2");
    VkFence done = gpu.fence();
    vk_ok(vkQueueSubmit2(gpu.queue, 1, &submits[1], done), "vkQueueSubmit2");
    gpu.wait(done);
    print_range("clas_addresses", clas.addresses.address, clas.addresses.size);
    vkDestroySemaphore(gpu.device, clusters_done, nullptr);
    return 0;
}
