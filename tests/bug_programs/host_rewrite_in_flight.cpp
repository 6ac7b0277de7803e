// SPDX-License-Identifier: Apache-2.0
// Bug: the host prepares the next frame's src infos in the same mapped buffer right after
// vkQueueSubmit, before waiting on the fence, while the submitted cluster build may still read
// them. --fixed waits on the fence first.
#include "bug_gpu.h"

using namespace bug_programs;

int main(int argc, char** argv) {
    const bool fixed = has_flag(argc, argv, "--fixed");
    Gpu gpu;
    open(gpu, "host_rewrite_in_flight");
    const Quads quads = make_quads(gpu, 4);
    ClasBuild clas;
    prepare_clas_build(gpu, quads, clas);

    VkCommandBuffer cb = gpu.begin();
    gpu.cmd_build_clusters(cb, &clas.info);
    VkFence done = gpu.fence();
    gpu.submit(cb, done);
    if (fixed) gpu.wait(done);
    // Next frame: the same clusters under new IDs.
    const uint32_t info_size = sizeof(VkClusterAccelerationStructureBuildTriangleClusterInfoNV);
    for (uint32_t c = 0; c < quads.count; ++c) {
        const uint32_t next_id = 100 + c;
        std::memcpy(clas.infos.host + VkDeviceSize(c) * info_size, &next_id, sizeof next_id);
    }
    if (!fixed) gpu.wait(done);
    print_range("infos", clas.infos.address, clas.infos.size);
    return 0;
}
