// SPDX-License-Identifier: Apache-2.0
// Two devices in turn, for the capture test of the layer's per-device tables (forget_khr_device
// at vkDestroyDevice; tests/capture/khr_two_devices_test.cpp, lavapipe 25). Each round creates
// an instance and a device, builds a one-triangle KHR BLAS (allowing compaction), writes its
// compacted size into a query pool and reads it back, then destroys the device with the BLAS and
// the pool still alive, as programs that exit do. Round 2 first makes a timestamp query pool and
// reads it: the driver tends to hand round 1's freed handles out again, so the layer must not
// take it for round 1's property pool. Writes each round's handles to OUT.json. Exit 0; 2 when a
// Vulkan call fails.
#include "cluster_test_device.h"

#include <nlohmann/json.hpp>

#include <cstdint>
#include <cstdio>
#include <cstring>
#include <fstream>

namespace {

using clastrace::testapp::Buffer;
using clastrace::testapp::ClusterTestDevice;
using nlohmann::json;

uint64_t id(const void* handle) { return uint64_t(reinterpret_cast<uintptr_t>(handle)); }

template <typename Function>
Function load(const ClusterTestDevice& d, const char* name) {
    auto f = reinterpret_cast<Function>(vkGetDeviceProcAddr(d.device, name));
    if (!f) clastrace::testapp::fail("no VK_KHR_acceleration_structure");
    return f;
}

// A timestamp written and read back: a query pool that holds no structure property.
VkQueryPool read_timestamp(ClusterTestDevice& d) {
    VkQueryPool pool = d.makeQueryPool(VK_QUERY_TYPE_TIMESTAMP);
    VkCommandBuffer cb = d.beginCommands();
    vkCmdResetQueryPool(cb, pool, 0, 1);
    vkCmdWriteTimestamp(cb, VK_PIPELINE_STAGE_BOTTOM_OF_PIPE_BIT, pool, 0);
    d.submitAndWait(cb);
    d.queryResult(pool);
    return pool;
}

// One triangle at z = 2.
const float kTriangle[3][3] = {{-1, -1, 2}, {1, -1, 2}, {0, 1, 2}};

// The BLAS built and its compacted size read back; its handles in `out`.
void build_and_query(ClusterTestDevice& d, json& out, bool destroy_property_pool) {
    auto create = load<PFN_vkCreateAccelerationStructureKHR>(d, "vkCreateAccelerationStructureKHR");
    auto sizes_of = load<PFN_vkGetAccelerationStructureBuildSizesKHR>(
        d, "vkGetAccelerationStructureBuildSizesKHR");
    auto address_of = load<PFN_vkGetAccelerationStructureDeviceAddressKHR>(
        d, "vkGetAccelerationStructureDeviceAddressKHR");
    auto build =
        load<PFN_vkCmdBuildAccelerationStructuresKHR>(d, "vkCmdBuildAccelerationStructuresKHR");
    auto write_properties = load<PFN_vkCmdWriteAccelerationStructuresPropertiesKHR>(
        d, "vkCmdWriteAccelerationStructuresPropertiesKHR");
    const VkBufferUsageFlags usage =
        VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_BIT_KHR |
        VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_STORAGE_BIT_KHR;
    Buffer vertices = d.makeBuffer(sizeof kTriangle, usage);
    std::memcpy(vertices.mapped, kTriangle, sizeof kTriangle);
    Buffer storage = d.makeBuffer(1 << 16, usage), scratch = d.makeBuffer(1 << 16, usage);

    VkAccelerationStructureGeometryKHR geometry{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_GEOMETRY_KHR};
    geometry.geometryType = VK_GEOMETRY_TYPE_TRIANGLES_KHR;
    geometry.flags = VK_GEOMETRY_OPAQUE_BIT_KHR;
    auto& t = geometry.geometry.triangles;
    t.sType = VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_GEOMETRY_TRIANGLES_DATA_KHR;
    t.vertexFormat = VK_FORMAT_R32G32B32_SFLOAT;
    t.vertexData.deviceAddress = vertices.address;
    t.vertexStride = 12;
    t.maxVertex = 2;
    t.indexType = VK_INDEX_TYPE_NONE_KHR;
    VkAccelerationStructureBuildGeometryInfoKHR info{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_BUILD_GEOMETRY_INFO_KHR};
    info.type = VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR;
    info.flags = VK_BUILD_ACCELERATION_STRUCTURE_ALLOW_COMPACTION_BIT_KHR;
    info.mode = VK_BUILD_ACCELERATION_STRUCTURE_MODE_BUILD_KHR;
    info.geometryCount = 1;
    info.pGeometries = &geometry;
    const uint32_t primitives = 1;
    VkAccelerationStructureBuildSizesInfoKHR sizes{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_BUILD_SIZES_INFO_KHR};
    sizes_of(d.device, VK_ACCELERATION_STRUCTURE_BUILD_TYPE_DEVICE_KHR, &info, &primitives, &sizes);
    if (sizes.accelerationStructureSize > storage.size || sizes.buildScratchSize > scratch.size)
        clastrace::testapp::fail("the BLAS needs more than 64 KiB");
    VkAccelerationStructureCreateInfoKHR create_info{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_CREATE_INFO_KHR};
    create_info.buffer = storage.buffer;
    create_info.size = sizes.accelerationStructureSize;
    create_info.type = VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR;
    VkAccelerationStructureKHR blas;
    CHECK(create(d.device, &create_info, nullptr, &blas));
    VkAccelerationStructureDeviceAddressInfoKHR address_info{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_DEVICE_ADDRESS_INFO_KHR, nullptr, blas};
    const VkDeviceAddress address = address_of(d.device, &address_info);
    info.dstAccelerationStructure = blas;
    info.scratchData.deviceAddress = scratch.address;
    const VkAccelerationStructureBuildRangeInfoKHR range{1, 0, 0, 0};
    const VkAccelerationStructureBuildRangeInfoKHR* ranges = &range;

    VkQueryPool compacted =
        d.makeQueryPool(VK_QUERY_TYPE_ACCELERATION_STRUCTURE_COMPACTED_SIZE_KHR);
    VkCommandBuffer cb = d.beginCommands();
    build(cb, 1, &info, &ranges);
    VkMemoryBarrier built{VK_STRUCTURE_TYPE_MEMORY_BARRIER, nullptr,
                          VK_ACCESS_ACCELERATION_STRUCTURE_WRITE_BIT_KHR,
                          VK_ACCESS_ACCELERATION_STRUCTURE_READ_BIT_KHR};
    vkCmdPipelineBarrier(cb, VK_PIPELINE_STAGE_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                         VK_PIPELINE_STAGE_ACCELERATION_STRUCTURE_BUILD_BIT_KHR, 0, 1, &built, 0,
                         nullptr, 0, nullptr);
    vkCmdResetQueryPool(cb, compacted, 0, 1);
    write_properties(cb, 1, &blas, VK_QUERY_TYPE_ACCELERATION_STRUCTURE_COMPACTED_SIZE_KHR,
                     compacted, 0);
    d.submitAndWait(cb);
    out["compactedSize"] = d.queryResult(compacted);
    out["blas"] = id(blas);
    out["address"] = address;
    out["propertyPool"] = id(compacted);
    out["storage"] = id(storage.buffer);
    if (!destroy_property_pool) return;
    // The property pool goes, and a timestamp pool is made and read after it: where the driver
    // hands the handle back, the layer must not take that read for a property read.
    vkDestroyQueryPool(d.device, compacted, nullptr);
    const VkQueryPool later = read_timestamp(d);
    out["laterTimestampPool"] = id(later);
    out["handleReused"] = id(later) == id(compacted);
}

}  // namespace

int main(int argc, char** argv) {
    if (argc != 2) {
        std::fprintf(stderr, "usage: khr_two_devices_app OUT.json\n");
        return 2;
    }
    json rounds = json::array();
    for (int round = 0; round < 2; ++round) {
        ClusterTestDevice d;
        d.clusters = false;
        d.rayTracing = true;
        d.rayQuery = false;
        d.createInstance();
        d.createDevice();
        json out;
        out["device"] = id(d.device);
        if (round == 1) out["timestampPool"] = id(read_timestamp(d));
        build_and_query(d, out, round == 1);
        rounds.push_back(out);
        d.destroy();  // the BLAS and the query pools are left to the device's end
    }
    std::ofstream(argv[1]) << json{{"rounds", rounds}}.dump(1);
    std::printf("ok\n");
    return 0;
}
