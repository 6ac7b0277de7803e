// SPDX-License-Identifier: Apache-2.0
// Bug: an animation step rewrites one cluster's vertices with vkCmdUpdateBuffer, and the
// barrier before the cluster build names COMPUTE_SHADER as its destination stage (the author
// took builds for compute work), so the build's vertex reads are outside its scope. --fixed
// names ACCELERATION_STRUCTURE_BUILD.
#include "bug_gpu.h"

using namespace bug_programs;

int main(int argc, char** argv) {
    const bool fixed = has_flag(argc, argv, "--fixed");
    Gpu gpu;
    open(gpu, "vertices_update_wrong_stage");
    const Quads quads = make_quads(gpu, 3);
    ClasBuild clas;
    prepare_clas_build(gpu, quads, clas);

    // Cluster 1's four vertices, lifted to z = 0.5.
    float lifted[12];
    std::memcpy(lifted, quads.vertices.host + sizeof lifted, sizeof lifted);
    for (int k = 0; k < 4; ++k) lifted[k * 3 + 2] = 0.5f;
    VkCommandBuffer cb = gpu.begin();
    vkCmdUpdateBuffer(cb, quads.vertices.buffer, sizeof lifted, sizeof lifted, lifted);
    memory_barrier(cb, VK_PIPELINE_STAGE_2_ALL_TRANSFER_BIT, VK_ACCESS_2_TRANSFER_WRITE_BIT,
                   fixed ? VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR
                         : VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT,
                   VK_ACCESS_2_SHADER_READ_BIT);
    gpu.cmd_build_clusters(cb, &clas.info);
    gpu.submit_and_wait(cb);
    print_range("lifted", quads.vertices.address + sizeof lifted, sizeof lifted);
    return 0;
}
