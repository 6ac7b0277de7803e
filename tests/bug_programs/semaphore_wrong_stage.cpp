// SPDX-License-Identifier: Apache-2.0
// Bug: the cluster build and the bottom level over it go in two vkQueueSubmit calls joined by
// a binary semaphore, but the second waits on it at COMPUTE_SHADER only (the author's compute
// culling pass came first once): the bottom level's ACCELERATION_STRUCTURE_BUILD stage is not
// in the wait's second scope, so it may read the CLAS before they are written. --fixed waits
// at ACCELERATION_STRUCTURE_BUILD.
#include "bug_gpu.h"

using namespace bug_programs;

int main(int argc, char** argv) {
    const bool fixed = has_flag(argc, argv, "--fixed");
    Gpu gpu;
    open(gpu, "semaphore_wrong_stage");
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

    VkSubmitInfo signal{VK_STRUCTURE_TYPE_SUBMIT_INFO};
    signal.commandBufferCount = 1;
    signal.pCommandBuffers = &first;
    signal.signalSemaphoreCount = 1;
    signal.pSignalSemaphores = &clusters_done;
    vk_ok(vkQueueSubmit(gpu.queue, 1, &signal, VK_NULL_HANDLE), "vkQueueSubmit");
    const VkPipelineStageFlags wait_stage =
        fixed ? VK_PIPELINE_STAGE_ACCELERATION_STRUCTURE_BUILD_BIT_KHR
              : VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT;
    VkSubmitInfo wait{VK_STRUCTURE_TYPE_SUBMIT_INFO};
    wait.waitSemaphoreCount = 1;
    wait.pWaitSemaphores = &clusters_done;
    wait.pWaitDstStageMask = &wait_stage;
    wait.commandBufferCount = 1;
    wait.pCommandBuffers = &second;
    VkFence done = gpu.fence();
    vk_ok(vkQueueSubmit(gpu.queue, 1, &wait, done), "vkQueueSubmit");
    gpu.wait(done);
    print_range("clas_addresses", clas.addresses.address, clas.addresses.size);
    print_range("clas_objects", clas.objects.address, clas.objects.size);
    vkDestroySemaphore(gpu.device, clusters_done, nullptr);
    return 0;
}
