// SPDX-License-Identifier: Apache-2.0
// Bug: the cluster build's scratch is half the buildScratchSize that
// vkGetClusterAccelerationStructureBuildSizesNV answered for its input (the author halved it,
// reasoning that the clusters are small). --fixed allocates the answered size.
#include "bug_gpu.h"

using namespace bug_programs;

int main(int argc, char** argv) {
    const bool fixed = has_flag(argc, argv, "--fixed");
    Gpu gpu;
    open(gpu, "scratch_too_small");
    const Quads quads = make_quads(gpu, 4);
    ClasBuild clas;
    prepare_clas_build(gpu, quads, clas);
    Buffer half = gpu.buffer(clas.scratch.size / 2);
    if (!fixed) clas.info.scratchData = half.address;

    VkCommandBuffer cb = gpu.begin();
    gpu.cmd_build_clusters(cb, &clas.info);
    gpu.submit_and_wait(cb);
    print_range("scratch", half.address, half.size);
    return 0;
}
