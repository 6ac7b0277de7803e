// SPDX-License-Identifier: Apache-2.0
// The cluster count comes from the GPU: a culling pass leaves it in a buffer of its own, and a
// vkCmdCopyBuffer hands it to the build's srcInfosCount. One bug per run:
//   (none)          the build follows the copy with no barrier, so it may read the count
//                   before the copy wrote it
//   --above-max     behind the barrier, the count the GPU hands on (5) is larger than the
//                   build's maxAccelerationStructureCount (4)
//   --fixed         the barrier (COPY/TRANSFER_WRITE -> BUILD/INDIRECT_COMMAND_READ), count 4
#include "bug_gpu.h"

using namespace bug_programs;

int main(int argc, char** argv) {
    const bool above_max = has_flag(argc, argv, "--above-max");
    const bool ordered = above_max || has_flag(argc, argv, "--fixed");
    Gpu gpu;
    open(gpu, "count_written_no_barrier");
    const Quads quads = make_quads(gpu, 4);
    ClasBuild clas;
    prepare_clas_build(gpu, quads, clas);
    Buffer culled = gpu.buffer(sizeof(uint32_t));
    const uint32_t visible = above_max ? quads.count + 1 : quads.count;
    std::memcpy(culled.host, &visible, sizeof visible);
    std::memset(clas.count.host, 0, sizeof(uint32_t));

    VkCommandBuffer cb = gpu.begin();
    const VkBufferCopy count_copy{0, 0, sizeof(uint32_t)};
    vkCmdCopyBuffer(cb, culled.buffer, clas.count.buffer, 1, &count_copy);
    if (ordered)
        memory_barrier(cb, VK_PIPELINE_STAGE_2_COPY_BIT, VK_ACCESS_2_TRANSFER_WRITE_BIT,
                       VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                       VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT);
    gpu.cmd_build_clusters(cb, &clas.info);
    gpu.submit_and_wait(cb);
    print_range("count", clas.count.address, sizeof(uint32_t));
    return 0;
}
