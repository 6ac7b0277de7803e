// SPDX-License-Identifier: Apache-2.0
// Bug (VK_KHR_acceleration_structure): each frame the top level's instances are uploaded by a
// staging copy (vkCmdCopyBuffer) and the top level is built right after it with no barrier, so
// the build may read instances the copy has not written. --fixed records COPY/TRANSFER_WRITE
// -> ACCELERATION_STRUCTURE_BUILD/SHADER_READ between them.
#include "bug_khr.h"

using namespace bug_programs;

int main(int argc, char** argv) {
    const bool fixed = has_flag(argc, argv, "--fixed");
    Gpu gpu;
    open(gpu, "khr_instances_copy_no_barrier");
    const KhrCalls khr = load_khr(gpu);

    Buffer vertices = gpu.buffer(kTriangleBytes);
    const VkAccelerationStructureGeometryKHR triangles = triangle_geometry(vertices);
    Structure bottom;
    create(gpu, khr, VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR, triangles, bottom);
    VkCommandBuffer load = gpu.begin();
    cmd_build(khr, load, bottom);
    gpu.submit_and_wait(load);

    Buffer instances = gpu.buffer(sizeof(VkAccelerationStructureInstanceKHR));
    Buffer staging = gpu.buffer(instances.size);
    const VkAccelerationStructureInstanceKHR instance = identity_instance(bottom.address);
    std::memcpy(staging.host, &instance, sizeof instance);
    const VkAccelerationStructureGeometryKHR instanced = instance_geometry(instances);
    Structure top;
    create(gpu, khr, VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_KHR, instanced, top);

    VkCommandBuffer frame = gpu.begin();
    const VkBufferCopy whole{0, 0, instances.size};
    vkCmdCopyBuffer(frame, staging.buffer, instances.buffer, 1, &whole);
    if (fixed)
        memory_barrier(frame, VK_PIPELINE_STAGE_2_COPY_BIT, VK_ACCESS_2_TRANSFER_WRITE_BIT,
                       VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                       VK_ACCESS_2_SHADER_READ_BIT);
    cmd_build(khr, frame, top);
    gpu.submit_and_wait(frame);
    print_range("instances", instances.address, instances.size);
    khr.destroy(gpu.device, top.handle, nullptr);
    khr.destroy(gpu.device, bottom.handle, nullptr);
    return 0;
}
