// SPDX-License-Identifier: Apache-2.0
// Bug: the engine sizes srcInfosArray for the clusters of the previous frame (2) while the
// count it hands the build (srcInfosCount) is this frame's (3): the region holds fewer inputs
// than the count asks for (VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-
// pCommandInfos-10454). The third info's bytes lie in the buffer, so a driver may read them
// anyway. --fixed sizes the region for 3.
#include "bug_gpu.h"

using namespace bug_programs;

int main(int argc, char** argv) {
    const bool fixed = has_flag(argc, argv, "--fixed");
    Gpu gpu;
    open(gpu, "infos_array_short");
    const Quads quads = make_quads(gpu, 3);
    ClasBuild clas;
    prepare_clas_build(gpu, quads, clas);
    if (!fixed) clas.info.srcInfosArray.size = 2 * clas.info.srcInfosArray.stride;

    VkCommandBuffer cb = gpu.begin();
    gpu.cmd_build_clusters(cb, &clas.info);
    gpu.submit_and_wait(cb);
    print_range("count", clas.count.address, sizeof(uint32_t));
    print_range("infos", clas.info.srcInfosArray.deviceAddress, clas.info.srcInfosArray.size);
    return 0;
}
