// SPDX-License-Identifier: Apache-2.0
// Bug: a compute pass writes the cluster build's src infos (a GPU-driven engine's culling
// output), and the build follows the dispatch with no barrier, so it may read infos the shader
// has not written yet. --fixed records COMPUTE_SHADER/SHADER_WRITE ->
// ACCELERATION_STRUCTURE_BUILD/INDIRECT_COMMAND_READ between them.
#include "bug_compute.h"

using namespace bug_programs;

int main(int argc, char** argv) {
    const bool fixed = has_flag(argc, argv, "--fixed");
    Gpu gpu;
    open(gpu, "dispatch_writes_infos");
    const Quads quads = make_quads(gpu, 4);
    ClasBuild clas;
    prepare_clas_build(gpu, quads, clas);
    Buffer visible = gpu.buffer(clas.infos.size);
    std::memcpy(visible.host, clas.infos.host, clas.infos.size);
    std::memset(clas.infos.host, 0, clas.infos.size);
    CopyPass pass = make_copy_pass(gpu, visible, clas.infos);

    VkCommandBuffer cb = gpu.begin();
    record_copy(cb, pass, uint32_t(clas.infos.size / sizeof(uint32_t)));
    if (fixed)
        memory_barrier(cb, VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT,
                       VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT,
                       VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                       VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT);
    gpu.cmd_build_clusters(cb, &clas.info);
    gpu.submit_and_wait(cb);
    if (std::memcmp(visible.host, clas.infos.host, clas.infos.size) != 0)
        die("the compute pass did not write the infos");
    destroy(gpu, pass);
    print_range("infos", clas.infos.address, clas.infos.size);
    return 0;
}
