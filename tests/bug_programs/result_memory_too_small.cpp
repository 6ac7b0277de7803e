// SPDX-License-Identifier: Apache-2.0
// Three CLAS and a bottom level over them, built behind the right barrier; the memory one of
// them writes its results to is too small. One bug per run:
//   (none)           the bottom level's dstImplicitData lies in a buffer half the
//                    accelerationStructureSize vkGetClusterAccelerationStructureBuildSizesNV
//                    answered (the author sized it by hand)
//   --sizes-short    the cluster build also asks for each CLAS's size (dstSizesArray, stride
//                    4: the driver writes uint32_t) into a buffer the author sized for three
//                    uint16_t, so the second size runs off its end
//   --fixed          the queried size, and no sizes array
#include "bug_gpu.h"

using namespace bug_programs;

int main(int argc, char** argv) {
    const bool fixed = has_flag(argc, argv, "--fixed");
    const bool sizes_short = has_flag(argc, argv, "--sizes-short");
    Gpu gpu;
    open(gpu, "result_memory_too_small");
    const Quads quads = make_quads(gpu, 3);
    ClasBuild clas;
    prepare_clas_build(gpu, quads, clas);
    BlasBuild blas;
    prepare_blas_build(gpu, clas, quads.count, blas);
    Buffer half = gpu.buffer(blas.objects.size / 2);
    if (!fixed && !sizes_short) blas.info.dstImplicitData = half.address;
    Buffer sizes = gpu.buffer(quads.count * sizeof(uint16_t));
    if (sizes_short)
        clas.info.dstSizesArray = {sizes.address, sizeof(uint32_t), quads.count * sizeof(uint32_t)};

    VkCommandBuffer cb = gpu.begin();
    gpu.cmd_build_clusters(cb, &clas.info);
    build_to_build_barrier(cb);
    gpu.cmd_build_clusters(cb, &blas.info);
    gpu.submit_and_wait(cb);
    print_range("implicit_data", half.address, half.size);
    print_range("sizes", sizes.address, sizes.size);
    return 0;
}
