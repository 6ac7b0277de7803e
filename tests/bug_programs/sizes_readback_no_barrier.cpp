// SPDX-License-Identifier: Apache-2.0
// Bug: the cluster build writes each CLAS's size (dstSizesArray) for a later compaction, and a
// vkCmdCopyBuffer takes the sizes to a read-back buffer right after the build, with no
// barrier, so it may copy them before the build wrote them. --fixed records
// BUILD/ACCELERATION_STRUCTURE_WRITE -> COPY/TRANSFER_READ between them.
#include "bug_gpu.h"

using namespace bug_programs;

int main(int argc, char** argv) {
    const bool fixed = has_flag(argc, argv, "--fixed");
    Gpu gpu;
    open(gpu, "sizes_readback_no_barrier");
    const Quads quads = make_quads(gpu, 4);
    ClasBuild clas;
    prepare_clas_build(gpu, quads, clas);
    Buffer sizes = gpu.buffer(quads.count * sizeof(uint32_t));
    clas.info.dstSizesArray = {sizes.address, sizeof(uint32_t), sizes.size};
    Buffer readback = gpu.buffer(sizes.size);

    VkCommandBuffer cb = gpu.begin();
    gpu.cmd_build_clusters(cb, &clas.info);
    if (fixed)
        memory_barrier(cb, VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                       VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR,
                       VK_PIPELINE_STAGE_2_COPY_BIT, VK_ACCESS_2_TRANSFER_READ_BIT);
    const VkBufferCopy all{0, 0, sizes.size};
    vkCmdCopyBuffer(cb, sizes.buffer, readback.buffer, 1, &all);
    gpu.submit_and_wait(cb);
    print_range("sizes", sizes.address, sizes.size);
    return 0;
}
