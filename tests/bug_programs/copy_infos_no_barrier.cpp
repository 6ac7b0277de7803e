// SPDX-License-Identifier: Apache-2.0
// Bug: the src infos reach the device through a staging copy (vkCmdCopyBuffer), and the cluster
// build that reads them follows the copy with no barrier. --fixed records the barrier
// (COPY/TRANSFER_WRITE -> ACCELERATION_STRUCTURE_BUILD/INDIRECT_COMMAND_READ).
#include "bug_gpu.h"

using namespace bug_programs;

int main(int argc, char** argv) {
    const bool fixed = has_flag(argc, argv, "--fixed");
    Gpu gpu;
    open(gpu, "copy_infos_no_barrier");
    const Quads quads = make_quads(gpu, 4);
    ClasBuild clas;
    prepare_clas_build(gpu, quads, clas);
    Buffer staging = gpu.buffer(clas.infos.size);
    std::memcpy(staging.host, clas.infos.host, clas.infos.size);
    std::memset(clas.infos.host, 0, clas.infos.size);

    VkCommandBuffer cb = gpu.begin();
    const VkBufferCopy whole{0, 0, clas.infos.size};
    vkCmdCopyBuffer(cb, staging.buffer, clas.infos.buffer, 1, &whole);
    if (fixed)
        memory_barrier(cb, VK_PIPELINE_STAGE_2_COPY_BIT, VK_ACCESS_2_TRANSFER_WRITE_BIT,
                       VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                       VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT);
    gpu.cmd_build_clusters(cb, &clas.info);
    gpu.submit_and_wait(cb);
    print_range("infos", clas.infos.address, clas.infos.size);
    return 0;
}
