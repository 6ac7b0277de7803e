// SPDX-License-Identifier: Apache-2.0
// Bug: the cluster build and the bottom level over it go in two submissions to the queue, one
// after the other, and nothing orders the second after the first's writes: no semaphore, no
// barrier (submission order alone is no memory dependency). --fixed signals a semaphore from
// the first and waits on it at ACCELERATION_STRUCTURE_BUILD in the second.
#include "bug_gpu.h"

using namespace bug_programs;

int main(int argc, char** argv) {
    const bool fixed = has_flag(argc, argv, "--fixed");
    Gpu gpu;
    open(gpu, "blas_next_submission");
    const Quads quads = make_quads(gpu, 3);
    ClasBuild clas;
    prepare_clas_build(gpu, quads, clas);
    BlasBuild blas;
    prepare_blas_build(gpu, clas, quads.count, blas);
    VkSemaphoreCreateInfo semaphore_info{VK_STRUCTURE_TYPE_SEMAPHORE_CREATE_INFO};
    VkSemaphore clusters_done = VK_NULL_HANDLE;
    vk_ok(vkCreateSemaphore(gpu.device, &semaphore_info, nullptr, &clusters_done),
          "vkCreateSemaphore");

    VkCommandBuffer first = gpu.begin();
    gpu.cmd_build_clusters(first, &clas.info);
    vk_ok(vkEndCommandBuffer(first), "vkEndCommandBuffer");
    VkCommandBuffer second = gpu.begin();
    gpu.cmd_build_clusters(second, &blas.info);
    vk_ok(vkEndCommandBuffer(second), "vkEndCommandBuffer");

    VkCommandBufferSubmitInfo commands[2] = {{VK_STRUCTURE_TYPE_COMMAND_BUFFER_SUBMIT_INFO},
                                             {VK_STRUCTURE_TYPE_COMMAND_BUFFER_SUBMIT_INFO}};
    commands[0].commandBuffer = first;
    commands[1].commandBuffer = second;
    VkSemaphoreSubmitInfo signal{VK_STRUCTURE_TYPE_SEMAPHORE_SUBMIT_INFO};
    signal.semaphore = clusters_done;
    signal.stageMask = VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR;
    VkSemaphoreSubmitInfo wait = signal;
    VkSubmitInfo2 submits[2] = {{VK_STRUCTURE_TYPE_SUBMIT_INFO_2},
                                {VK_STRUCTURE_TYPE_SUBMIT_INFO_2}};
    submits[0].commandBufferInfoCount = 1;
    submits[0].pCommandBufferInfos = &commands[0];
    submits[1].commandBufferInfoCount = 1;
    submits[1].pCommandBufferInfos = &commands[1];
    if (fixed) {
        submits[0].signalSemaphoreInfoCount = 1;
        submits[0].pSignalSemaphoreInfos = &signal;
        submits[1].waitSemaphoreInfoCount = 1;
        submits[1].pWaitSemaphoreInfos = &wait;
    }
    vk_ok(vkQueueSubmit2(gpu.queue, 1, &submits[0], VK_NULL_HANDLE), "vkQueueSubmit2");
    VkFence done = gpu.fence();
    vk_ok(vkQueueSubmit2(gpu.queue, 1, &submits[1], done), "vkQueueSubmit2");
    gpu.wait(done);
    print_range("clas_addresses", clas.addresses.address, clas.addresses.size);
    print_range("clas_objects", clas.objects.address, clas.objects.size);
    vkDestroySemaphore(gpu.device, clusters_done, nullptr);
    return 0;
}
