// SPDX-License-Identifier: Apache-2.0
// One valid-usage rule that only the memory the build reads decides, chosen by the first
// argument (one bug per run; no argument: the valid build):
//   index-out-of-range  cluster 1's index buffer names vertex 7 of a 4-vertex cluster
//   too-many-triangles  cluster 0 says 3 triangles where the input's maxClusterTriangleCount is 2
//   count-above-max     srcInfosCount holds 5 where maxAccelerationStructureCount is 4
//   misaligned-dst      explicit destinations, the second one 16 bytes past the alignment
//   overlapping-dst     explicit destinations, the second one 128 bytes into the first
//   dst-too-small       explicit destinations with dstSizesArray, the second size 128 bytes
//   aligned-dst         (no bug) explicit destinations, each in a slot of its own
#include "bug_gpu.h"

#include <string>

using namespace bug_programs;

int main(int argc, char** argv) {
    const std::string bug = argc > 1 ? argv[1] : "";
    Gpu gpu;
    open(gpu, "memory_rules");
    const Quads quads = make_quads(gpu, 4);
    ClasBuild clas;
    prepare_clas_build(gpu, quads, clas);
    using Info = VkClusterAccelerationStructureBuildTriangleClusterInfoNV;
    auto* infos = reinterpret_cast<Info*>(clas.infos.host);

    if (bug == "index-out-of-range") {
        reinterpret_cast<uint32_t*>(quads.indices.host)[6 + 2] = 7;
    } else if (bug == "too-many-triangles") {
        infos[0].triangleCount = 3;
    } else if (bug == "count-above-max") {
        const uint32_t five = 5;
        std::memcpy(clas.count.host, &five, sizeof five);
    } else if (bug == "misaligned-dst" || bug == "overlapping-dst" || bug == "dst-too-small" ||
               bug == "aligned-dst") {
        // Explicit mode: the application places every CLAS itself, each in a slot as large as
        // the driver's answer for the whole input (more than one cluster needs).
        clas.info.input.opMode = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_EXPLICIT_DESTINATIONS_NV;
        const VkDeviceSize alignment = gpu.cluster_props.clusterByteAlignment;
        const VkDeviceSize one =
            align_up(sizes_of(gpu, clas.info.input).accelerationStructureSize, alignment);
        clas.info.dstImplicitData = 0;
        Buffer place = gpu.buffer(one * (quads.count + 1));
        const VkDeviceAddress base = align_up(place.address, alignment);
        auto* destinations = reinterpret_cast<VkDeviceAddress*>(clas.addresses.host);
        for (uint32_t c = 0; c < quads.count; ++c) destinations[c] = base + c * one;
        if (bug == "misaligned-dst") destinations[1] += 16;
        if (bug == "overlapping-dst") destinations[1] = destinations[0] + alignment;
        if (bug == "dst-too-small") {
            // The sizes the application believes each slot holds (what the driver reads).
            Buffer sizes = gpu.buffer(sizeof(uint32_t) * quads.count);
            auto* size = reinterpret_cast<uint32_t*>(sizes.host);
            for (uint32_t c = 0; c < quads.count; ++c) size[c] = uint32_t(one);
            size[1] = 128;
            clas.info.dstSizesArray = {sizes.address, sizeof(uint32_t),
                                       sizeof(uint32_t) * quads.count};
        }
    } else if (!bug.empty()) {
        die("unknown bug name");
    }

    VkCommandBuffer cb = gpu.begin();
    gpu.cmd_build_clusters(cb, &clas.info);
    gpu.submit_and_wait(cb);
    print_range("cluster1_indices", quads.indices.address + 6 * sizeof(uint32_t),
                6 * sizeof(uint32_t));
    print_range("count", clas.count.address, sizeof(uint32_t));
    if (clas.info.input.opMode ==
        VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_EXPLICIT_DESTINATIONS_NV)
        print_range("destination1", reinterpret_cast<VkDeviceAddress*>(clas.addresses.host)[1], 0);
    return 0;
}
