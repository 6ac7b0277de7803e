// SPDX-License-Identifier: Apache-2.0
// Bug (VK_KHR_acceleration_structure): a bottom level built with ALLOW_COMPACTION, whose
// compacted size vkCmdWriteAccelerationStructuresPropertiesKHR writes to a query right after
// the build, in the same command buffer, with no barrier: the query may read the structure
// before its build is done. --fixed records BUILD/AS_WRITE -> BUILD/AS_READ between them.
#include "bug_khr.h"

using namespace bug_programs;

int main(int argc, char** argv) {
    const bool fixed = has_flag(argc, argv, "--fixed");
    Gpu gpu;
    open(gpu, "khr_compacted_size_no_barrier");
    const KhrCalls khr = load_khr(gpu);
    const auto write_properties = device_call<PFN_vkCmdWriteAccelerationStructuresPropertiesKHR>(
        gpu, "vkCmdWriteAccelerationStructuresPropertiesKHR");

    Buffer vertices = gpu.buffer(kTriangleBytes);
    const VkAccelerationStructureGeometryKHR triangles = triangle_geometry(vertices);
    Structure bottom;
    create(gpu, khr, VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR, triangles, bottom);
    bottom.build.flags |= VK_BUILD_ACCELERATION_STRUCTURE_ALLOW_COMPACTION_BIT_KHR;

    VkQueryPoolCreateInfo pool_info{VK_STRUCTURE_TYPE_QUERY_POOL_CREATE_INFO};
    pool_info.queryType = VK_QUERY_TYPE_ACCELERATION_STRUCTURE_COMPACTED_SIZE_KHR;
    pool_info.queryCount = 1;
    VkQueryPool pool = VK_NULL_HANDLE;
    vk_ok(vkCreateQueryPool(gpu.device, &pool_info, nullptr, &pool), "vkCreateQueryPool");

    VkCommandBuffer cb = gpu.begin();
    vkCmdResetQueryPool(cb, pool, 0, 1);
    cmd_build(khr, cb, bottom);
    if (fixed) build_to_build_barrier(cb);
    write_properties(cb, 1, &bottom.handle, VK_QUERY_TYPE_ACCELERATION_STRUCTURE_COMPACTED_SIZE_KHR,
                     pool, 0);
    gpu.submit_and_wait(cb);
    VkDeviceSize compacted = 0;
    vk_ok(vkGetQueryPoolResults(gpu.device, pool, 0, 1, sizeof compacted, &compacted,
                                sizeof compacted,
                                VK_QUERY_RESULT_64_BIT | VK_QUERY_RESULT_WAIT_BIT),
          "vkGetQueryPoolResults");
    print_range("bottom_level", bottom.storage.address, bottom.storage.size);
    vkDestroyQueryPool(gpu.device, pool, nullptr);
    khr.destroy(gpu.device, bottom.handle, nullptr);
    return 0;
}
