// SPDX-License-Identifier: Apache-2.0
// Bug: two frames in flight, one fence each. Frame 0 clears a buffer (fence 0), frame 1 builds
// the clusters (fence 1); before rewriting the mapped src infos for the next build the host
// waits on fence 0, the earlier frame's, so the build that reads them may still be running.
// --fixed waits on fence 1, the build's own.
#include "bug_gpu.h"

using namespace bug_programs;

int main(int argc, char** argv) {
    const bool fixed = has_flag(argc, argv, "--fixed");
    Gpu gpu;
    open(gpu, "wrong_fence_host_rewrite");
    const Quads quads = make_quads(gpu, 4);
    ClasBuild clas;
    prepare_clas_build(gpu, quads, clas);
    Buffer readback = gpu.buffer(256);

    VkFence frame_fences[2] = {gpu.fence(), gpu.fence()};
    VkCommandBuffer frame0 = gpu.begin();
    vkCmdFillBuffer(frame0, readback.buffer, 0, VK_WHOLE_SIZE, 0);
    gpu.submit(frame0, frame_fences[0]);
    VkCommandBuffer frame1 = gpu.begin();
    gpu.cmd_build_clusters(frame1, &clas.info);
    gpu.submit(frame1, frame_fences[1]);
    const int waited = fixed ? 1 : 0;
    vk_ok(vkWaitForFences(gpu.device, 1, &frame_fences[waited], VK_TRUE, UINT64_MAX),
          "vkWaitForFences");
    // The next build's clusters: the same geometry under new IDs.
    const uint32_t info_size = sizeof(VkClusterAccelerationStructureBuildTriangleClusterInfoNV);
    for (uint32_t c = 0; c < quads.count; ++c) {
        const uint32_t next_id = 200 + c;
        std::memcpy(clas.infos.host + VkDeviceSize(c) * info_size, &next_id, sizeof next_id);
    }
    gpu.wait(frame_fences[1 - waited]);
    vkDestroyFence(gpu.device, frame_fences[waited], nullptr);
    print_range("infos", clas.infos.address, clas.infos.size);
    return 0;
}
