// SPDX-License-Identifier: Apache-2.0
// The engine records its streaming work in secondary command buffers, one per job: the upload
// job copies the src infos from staging, the build job builds the clusters, and the frame's
// primary executes both. One bug per run:
//   (none)            both secondaries in one vkCmdExecuteCommands, no barrier anywhere: the
//                     build may read the infos before the copy wrote them
//   --fixed           the build job starts with the barrier (COPY/TRANSFER_WRITE ->
//                     BUILD/INDIRECT_COMMAND_READ); a barrier in a secondary orders what the
//                     primary executed before it
//   --fixed-primary   two vkCmdExecuteCommands calls with the barrier in the primary between
#include "bug_gpu.h"

using namespace bug_programs;

namespace {

VkCommandBuffer begin_secondary(Gpu& gpu) {
    VkCommandBufferAllocateInfo info{VK_STRUCTURE_TYPE_COMMAND_BUFFER_ALLOCATE_INFO};
    info.commandPool = gpu.pool;
    info.level = VK_COMMAND_BUFFER_LEVEL_SECONDARY;
    info.commandBufferCount = 1;
    VkCommandBuffer cb = VK_NULL_HANDLE;
    vk_ok(vkAllocateCommandBuffers(gpu.device, &info, &cb), "vkAllocateCommandBuffers");
    VkCommandBufferInheritanceInfo inherit{VK_STRUCTURE_TYPE_COMMAND_BUFFER_INHERITANCE_INFO};
    VkCommandBufferBeginInfo begin{VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO};
    begin.flags = VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT;
    begin.pInheritanceInfo = &inherit;
    vk_ok(vkBeginCommandBuffer(cb, &begin), "vkBeginCommandBuffer");
    return cb;
}

void copy_to_build_barrier(VkCommandBuffer cb) {
    memory_barrier(cb, VK_PIPELINE_STAGE_2_COPY_BIT, VK_ACCESS_2_TRANSFER_WRITE_BIT,
                   VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                   VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT);
}

}  // namespace

int main(int argc, char** argv) {
    const bool fixed = has_flag(argc, argv, "--fixed");
    const bool fixed_primary = has_flag(argc, argv, "--fixed-primary");
    Gpu gpu;
    open(gpu, "secondary_no_barrier");
    const Quads quads = make_quads(gpu, 4);
    ClasBuild clas;
    prepare_clas_build(gpu, quads, clas);
    Buffer staging = gpu.buffer(clas.infos.size);
    std::memcpy(staging.host, clas.infos.host, clas.infos.size);
    std::memset(clas.infos.host, 0, clas.infos.size);

    VkCommandBuffer upload = begin_secondary(gpu);
    const VkBufferCopy whole{0, 0, clas.infos.size};
    vkCmdCopyBuffer(upload, staging.buffer, clas.infos.buffer, 1, &whole);
    vk_ok(vkEndCommandBuffer(upload), "vkEndCommandBuffer");
    VkCommandBuffer build = begin_secondary(gpu);
    if (fixed) copy_to_build_barrier(build);
    gpu.cmd_build_clusters(build, &clas.info);
    vk_ok(vkEndCommandBuffer(build), "vkEndCommandBuffer");

    VkCommandBuffer frame = gpu.begin();
    if (fixed_primary) {
        vkCmdExecuteCommands(frame, 1, &upload);
        copy_to_build_barrier(frame);
        vkCmdExecuteCommands(frame, 1, &build);
    } else {
        const VkCommandBuffer jobs[2] = {upload, build};
        vkCmdExecuteCommands(frame, 2, jobs);
    }
    gpu.submit_and_wait(frame);
    print_range("infos", clas.infos.address, clas.infos.size);
    return 0;
}
