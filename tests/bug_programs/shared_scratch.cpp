// SPDX-License-Identifier: Apache-2.0
// Bug: two cluster builds in one command buffer (two meshes) share one scratch buffer with no
// barrier between them, so the second may overwrite scratch the first still uses. --fixed puts
// a BUILD -> BUILD barrier on acceleration-structure reads and writes between them.
#include "bug_gpu.h"

using namespace bug_programs;

int main(int argc, char** argv) {
    const bool fixed = has_flag(argc, argv, "--fixed");
    Gpu gpu;
    open(gpu, "shared_scratch");
    const Quads first_mesh = make_quads(gpu, 2);
    const Quads second_mesh = make_quads(gpu, 2);
    ClasBuild first, second;
    prepare_clas_build(gpu, first_mesh, first);
    prepare_clas_build(gpu, second_mesh, second);
    second.info.scratchData = first.scratch.address;

    VkCommandBuffer cb = gpu.begin();
    gpu.cmd_build_clusters(cb, &first.info);
    if (fixed)
        memory_barrier(cb, VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                       VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR,
                       VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                       VK_ACCESS_2_ACCELERATION_STRUCTURE_READ_BIT_KHR |
                           VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR);
    gpu.cmd_build_clusters(cb, &second.info);
    gpu.submit_and_wait(cb);
    print_range("scratch", first.scratch.address, first.scratch.size);
    return 0;
}
