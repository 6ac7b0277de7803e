// SPDX-License-Identifier: Apache-2.0
// Bug: the src infos arrive by a staging copy, and the buffer memory barrier after it has the
// right stages and accesses (COPY/TRANSFER_WRITE -> ACCELERATION_STRUCTURE_BUILD/
// INDIRECT_COMMAND_READ) but covers only the first info (size = one info where the author
// meant the array), so the build reads infos 1..3 unordered. --wrong-buffer has the other
// slip: the whole-size barrier names the staging buffer, not the infos. --fixed covers the
// infos whole.
#include "bug_gpu.h"

using namespace bug_programs;

int main(int argc, char** argv) {
    const bool fixed = has_flag(argc, argv, "--fixed");
    const bool wrong_buffer = has_flag(argc, argv, "--wrong-buffer");
    Gpu gpu;
    open(gpu, "barrier_wrong_range");
    const Quads quads = make_quads(gpu, 4);
    ClasBuild clas;
    prepare_clas_build(gpu, quads, clas);
    Buffer staging = gpu.buffer(clas.infos.size);
    std::memcpy(staging.host, clas.infos.host, clas.infos.size);
    std::memset(clas.infos.host, 0, clas.infos.size);
    const VkDeviceSize one_info = clas.info.srcInfosArray.stride;

    VkCommandBuffer cb = gpu.begin();
    const VkBufferCopy whole{0, 0, clas.infos.size};
    vkCmdCopyBuffer(cb, staging.buffer, clas.infos.buffer, 1, &whole);
    buffer_barrier(cb, wrong_buffer ? staging.buffer : clas.infos.buffer, 0,
                   fixed || wrong_buffer ? VK_WHOLE_SIZE : one_info, VK_PIPELINE_STAGE_2_COPY_BIT,
                   VK_ACCESS_2_TRANSFER_WRITE_BIT,
                   VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                   VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT);
    gpu.cmd_build_clusters(cb, &clas.info);
    gpu.submit_and_wait(cb);
    print_range("infos", clas.infos.address, clas.infos.size);
    print_range("infos_past_the_barrier", clas.infos.address + one_info,
                clas.infos.size - one_info);
    return 0;
}
