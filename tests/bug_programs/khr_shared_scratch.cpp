// SPDX-License-Identifier: Apache-2.0
// Bug (VK_KHR_acceleration_structure): two bottom levels are built one after the other in one
// command buffer, through two vkCmdBuildAccelerationStructuresKHR calls, over one scratch
// buffer the engine sized for the larger, with no barrier between: the second build may
// overwrite scratch the first still uses. --fixed records BUILD/AS_WRITE ->
// BUILD/AS_READ|AS_WRITE between them.
#include "bug_khr.h"

using namespace bug_programs;

int main(int argc, char** argv) {
    const bool fixed = has_flag(argc, argv, "--fixed");
    Gpu gpu;
    open(gpu, "khr_shared_scratch");
    const KhrCalls khr = load_khr(gpu);

    Buffer vertices[2] = {gpu.buffer(kTriangleBytes), gpu.buffer(kTriangleBytes)};
    const VkAccelerationStructureGeometryKHR triangles[2] = {triangle_geometry(vertices[0]),
                                                             triangle_geometry(vertices[1])};
    Structure bottom[2];
    create(gpu, khr, VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR, triangles[0], bottom[0]);
    create(gpu, khr, VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR, triangles[1], bottom[1]);
    const Buffer& scratch = bottom[0].scratch;
    bottom[1].build.scratchData.deviceAddress = scratch.address;

    VkCommandBuffer cb = gpu.begin();
    cmd_build(khr, cb, bottom[0]);
    if (fixed)
        memory_barrier(cb, VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                       VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR,
                       VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                       VK_ACCESS_2_ACCELERATION_STRUCTURE_READ_BIT_KHR |
                           VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR);
    cmd_build(khr, cb, bottom[1]);
    gpu.submit_and_wait(cb);
    print_range("scratch", scratch.address, scratch.size);
    khr.destroy(gpu.device, bottom[0].handle, nullptr);
    khr.destroy(gpu.device, bottom[1].handle, nullptr);
    return 0;
}
