// SPDX-License-Identifier: Apache-2.0
// Bug: the CLAS are built with implicit destinations, where the implementation chooses where
// each one lands in dstImplicitData and says so in dstAddressesArray; the author does not read
// those addresses and has the bottom level reference CLAS i at dstImplicitData + i * (the
// queried accelerationStructureSize / count), as if they were packed evenly. --fixed references
// the addresses the build wrote (dstAddressesArray), as the extension means.
#include "bug_gpu.h"

using namespace bug_programs;

int main(int argc, char** argv) {
    const bool fixed = has_flag(argc, argv, "--fixed");
    Gpu gpu;
    open(gpu, "blas_guessed_addresses");
    const Quads quads = make_quads(gpu, 3);
    ClasBuild clas;
    prepare_clas_build(gpu, quads, clas);
    BlasBuild blas;
    prepare_blas_build(gpu, clas, quads.count, blas);
    Buffer guessed = gpu.buffer(sizeof(VkDeviceAddress) * quads.count);
    const VkDeviceSize even = clas.objects.size / quads.count;
    auto* references = reinterpret_cast<VkDeviceAddress*>(guessed.host);
    for (uint32_t c = 0; c < quads.count; ++c) references[c] = clas.objects.address + c * even;
    if (!fixed) {
        auto* info =
            reinterpret_cast<VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV*>(
                blas.infos.host);
        info->clusterReferences = guessed.address;
    }

    VkCommandBuffer cb = gpu.begin();
    gpu.cmd_build_clusters(cb, &clas.info);
    build_to_build_barrier(cb);
    gpu.cmd_build_clusters(cb, &blas.info);
    gpu.submit_and_wait(cb);
    print_range("guessed_second", references[1], 0);
    return 0;
}
