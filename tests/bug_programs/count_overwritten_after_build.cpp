// SPDX-License-Identifier: Apache-2.0
// Bug: one command buffer per frame builds this frame's clusters and, right after recording the
// build, stages the next frame's cluster count into the same srcInfosCount buffer with
// vkCmdCopyBuffer, with no barrier: the copy may overwrite the count before the build read it
// (the build's read of the count happens when the build runs, not when it was recorded).
// --fixed records an execution barrier ACCELERATION_STRUCTURE_BUILD -> COPY between them.
#include "bug_gpu.h"

using namespace bug_programs;

int main(int argc, char** argv) {
    const bool fixed = has_flag(argc, argv, "--fixed");
    Gpu gpu;
    open(gpu, "count_overwritten_after_build");
    const Quads quads = make_quads(gpu, 3);
    ClasBuild clas;
    prepare_clas_build(gpu, quads, clas);
    Buffer next_count = gpu.buffer(sizeof(uint32_t));
    const uint32_t next_frame = 2;
    std::memcpy(next_count.host, &next_frame, sizeof next_frame);

    VkCommandBuffer cb = gpu.begin();
    gpu.cmd_build_clusters(cb, &clas.info);
    if (fixed)
        memory_barrier(cb, VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR, 0,
                       VK_PIPELINE_STAGE_2_COPY_BIT, 0);
    const VkBufferCopy count_copy{0, 0, sizeof(uint32_t)};
    vkCmdCopyBuffer(cb, next_count.buffer, clas.count.buffer, 1, &count_copy);
    gpu.submit_and_wait(cb);
    print_range("count", clas.count.address, sizeof(uint32_t));
    return 0;
}
