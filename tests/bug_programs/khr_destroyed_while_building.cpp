// SPDX-License-Identifier: Apache-2.0
// Bug (VK_KHR_acceleration_structure): a streaming engine builds a bottom level for a mesh,
// then learns the mesh was culled away and destroys the structure at once
// (vkDestroyAccelerationStructureKHR) while the submission that builds it is still pending
// (VUID-vkDestroyAccelerationStructureKHR-accelerationStructure-02442). --fixed waits on the
// build's fence first.
#include "bug_khr.h"

using namespace bug_programs;

int main(int argc, char** argv) {
    const bool fixed = has_flag(argc, argv, "--fixed");
    Gpu gpu;
    open(gpu, "khr_destroyed_while_building");
    const KhrCalls khr = load_khr(gpu);

    Buffer vertices = gpu.buffer(kTriangleBytes);
    const VkAccelerationStructureGeometryKHR triangle = triangle_geometry(vertices);
    Structure bottom;
    create(gpu, khr, VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR, triangle, bottom);

    VkCommandBuffer cb = gpu.begin();
    cmd_build(khr, cb, bottom);
    VkFence built = gpu.fence();
    gpu.submit(cb, built);
    if (fixed) gpu.wait(built);
    khr.destroy(gpu.device, bottom.handle, nullptr);  // culled: not needed after all
    if (!fixed) gpu.wait(built);
    print_range("structure", bottom.storage.address, bottom.storage.size);
    return 0;
}
