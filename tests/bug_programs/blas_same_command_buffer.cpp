// SPDX-License-Identifier: Apache-2.0
// Bug: the bottom level over the clusters is built right after the cluster build in the same
// command buffer with no barrier: it reads the CLAS addresses (its clusterReferences are the
// cluster build's dstAddressesArray) and the CLAS objects before they are visible. --fixed
// records BUILD/AS_WRITE -> BUILD/(AS_READ | SHADER_READ) between them: AS_READ for the CLAS
// objects, SHADER_READ for the reference array, a buffer the build reads as it reads vertices.
// --fixed-indirect names INDIRECT_COMMAND_READ for the reference array instead, as the command's
// page words it ("input data as identified by any used values of srcInfosArray").
// --fixed-as-samples records BUILD/(AS_WRITE | AS_READ) -> BUILD/(AS_WRITE | AS_READ), the
// barrier NVIDIA's cluster samples put between their cluster and bottom-level builds.
#include "bug_gpu.h"

using namespace bug_programs;

int main(int argc, char** argv) {
    const bool indirect = has_flag(argc, argv, "--fixed-indirect");
    const bool as_samples = has_flag(argc, argv, "--fixed-as-samples");
    const bool fixed = indirect || has_flag(argc, argv, "--fixed");
    constexpr VkAccessFlags2 kStructureAccess = VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR |
                                                VK_ACCESS_2_ACCELERATION_STRUCTURE_READ_BIT_KHR;
    Gpu gpu;
    open(gpu, "blas_same_command_buffer");
    const Quads quads = make_quads(gpu, 4);
    ClasBuild clas;
    prepare_clas_build(gpu, quads, clas);
    BlasBuild blas;
    prepare_blas_build(gpu, clas, quads.count, blas);

    VkCommandBuffer cb = gpu.begin();
    gpu.cmd_build_clusters(cb, &clas.info);
    if (fixed)
        memory_barrier(cb, VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                       VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR,
                       VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                       VK_ACCESS_2_ACCELERATION_STRUCTURE_READ_BIT_KHR |
                           (indirect ? VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT
                                     : VK_ACCESS_2_SHADER_READ_BIT));
    if (as_samples)
        memory_barrier(cb, VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                       kStructureAccess, VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                       kStructureAccess);
    gpu.cmd_build_clusters(cb, &blas.info);
    gpu.submit_and_wait(cb);
    print_range("clas_addresses", clas.addresses.address, clas.addresses.size);
    print_range("clas_objects", clas.objects.address, clas.objects.size);
    return 0;
}
