// SPDX-License-Identifier: Apache-2.0
// Bug: a culling dispatch writes the number of visible clusters into the build's srcInfosCount,
// and the engine orders it with the barrier its renderer uses before vkCmdDrawIndirectCount:
// COMPUTE_SHADER/SHADER_WRITE -> DRAW_INDIRECT/INDIRECT_COMMAND_READ. The cluster build reads
// the count at ACCELERATION_STRUCTURE_BUILD, not DRAW_INDIRECT, so the barrier's second scope
// misses it. --fixed: the barrier's destination stage ACCELERATION_STRUCTURE_BUILD.
#include "bug_compute.h"

using namespace bug_programs;

int main(int argc, char** argv) {
    const bool fixed = has_flag(argc, argv, "--fixed");
    Gpu gpu;
    open(gpu, "count_dispatch_draw_indirect");
    const Quads quads = make_quads(gpu, 4);
    ClasBuild clas;
    prepare_clas_build(gpu, quads, clas);
    Buffer culled = gpu.buffer(sizeof(uint32_t));
    std::memcpy(culled.host, &quads.count, sizeof quads.count);
    std::memset(clas.count.host, 0, sizeof(uint32_t));
    CopyPass pass = make_copy_pass(gpu, culled, clas.count);

    VkCommandBuffer cb = gpu.begin();
    record_copy(cb, pass, 1);
    memory_barrier(cb, VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT, VK_ACCESS_2_SHADER_WRITE_BIT,
                   fixed ? VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR
                         : VK_PIPELINE_STAGE_2_DRAW_INDIRECT_BIT,
                   VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT);
    gpu.cmd_build_clusters(cb, &clas.info);
    gpu.submit_and_wait(cb);
    if (std::memcmp(clas.count.host, &quads.count, sizeof quads.count) != 0)
        die("the culling pass did not write the count");
    destroy(gpu, pass);
    print_range("count", clas.count.address, sizeof(uint32_t));
    return 0;
}
