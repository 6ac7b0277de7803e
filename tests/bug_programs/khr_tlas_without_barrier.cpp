// SPDX-License-Identifier: Apache-2.0
// Bug (VK_KHR_acceleration_structure): the top level is built right after the bottom level it
// instances, in the same command buffer, with no barrier, so it may read the bottom level
// before its build is done. --fixed records BUILD/AS_WRITE -> BUILD/AS_READ between them.
#include "bug_khr.h"

using namespace bug_programs;

int main(int argc, char** argv) {
    const bool fixed = has_flag(argc, argv, "--fixed");
    Gpu gpu;
    open(gpu, "khr_tlas_without_barrier");
    const KhrCalls khr = load_khr(gpu);

    Buffer vertices = gpu.buffer(kTriangleBytes);
    const VkAccelerationStructureGeometryKHR triangles = triangle_geometry(vertices);
    Structure bottom;
    create(gpu, khr, VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR, triangles, bottom);

    Buffer instances = gpu.buffer(sizeof(VkAccelerationStructureInstanceKHR));
    const VkAccelerationStructureInstanceKHR instance = identity_instance(bottom.address);
    std::memcpy(instances.host, &instance, sizeof instance);
    const VkAccelerationStructureGeometryKHR instanced = instance_geometry(instances);
    Structure top;
    create(gpu, khr, VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_KHR, instanced, top);

    VkCommandBuffer cb = gpu.begin();
    cmd_build(khr, cb, bottom);
    if (fixed) build_to_build_barrier(cb);
    cmd_build(khr, cb, top);
    gpu.submit_and_wait(cb);
    print_range("bottom_level", bottom.storage.address, bottom.storage.size);
    khr.destroy(gpu.device, top.handle, nullptr);
    khr.destroy(gpu.device, bottom.handle, nullptr);
    return 0;
}
