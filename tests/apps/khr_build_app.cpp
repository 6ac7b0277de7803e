// SPDX-License-Identifier: Apache-2.0
// A headless VK_KHR_acceleration_structure program for the capture test of KHR builds
// (tests/capture/khr_build_capture_test.cpp; lavapipe 25 in CI). Submission 1: vertices, indices,
// a transform and AABBs copied with vkCmdCopyBuffer into a build-input buffer; an indexed-triangle
// BLAS (allowing compaction and update) and an AABB BLAS built by one
// vkCmdBuildAccelerationStructuresKHR; their compacted and serialization sizes queried; a TLAS over
// two instances (one per BLAS). Submission 2: the triangle BLAS compacted into a new structure,
// the TLAS serialized to memory, and the triangle BLAS updated in place from moved vertices.
// Writes what it passed (handles, addresses, the bytes of each input) to OUT.json. Exit 0; 2
// when a Vulkan call fails.
#include "cluster_test_device.h"

#include <nlohmann/json.hpp>

#include <cstdint>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <string>
#include <vector>

namespace {

using clastrace::testapp::Buffer;
using clastrace::testapp::ClusterTestDevice;
using clastrace::testapp::hex;
using nlohmann::json;

// The shared set-up with acceleration structures (no ray queries: the ray-check test sees the
// layer enable them) and the KHR entry points this program calls.
struct Device : ClusterTestDevice {
    PFN_vkCreateAccelerationStructureKHR create_structure = nullptr;
    PFN_vkGetAccelerationStructureBuildSizesKHR build_sizes = nullptr;
    PFN_vkGetAccelerationStructureDeviceAddressKHR structure_address = nullptr;
    PFN_vkCmdBuildAccelerationStructuresKHR cmd_build = nullptr;
    PFN_vkCmdWriteAccelerationStructuresPropertiesKHR cmd_write_properties = nullptr;
    PFN_vkCmdCopyAccelerationStructureKHR cmd_copy = nullptr;
    PFN_vkCmdCopyAccelerationStructureToMemoryKHR cmd_copy_to_memory = nullptr;
};

void create_device(Device& d) {
    d.createInstance();
    d.clusters = false;
    d.rayTracing = true;
    d.rayQuery = false;
    d.createDevice();
#define LOAD(member, name) \
    d.member = reinterpret_cast<PFN_##name>(vkGetDeviceProcAddr(d.device, #name))
    LOAD(create_structure, vkCreateAccelerationStructureKHR);
    LOAD(build_sizes, vkGetAccelerationStructureBuildSizesKHR);
    LOAD(structure_address, vkGetAccelerationStructureDeviceAddressKHR);
    LOAD(cmd_build, vkCmdBuildAccelerationStructuresKHR);
    LOAD(cmd_write_properties, vkCmdWriteAccelerationStructuresPropertiesKHR);
    LOAD(cmd_copy, vkCmdCopyAccelerationStructureKHR);
    LOAD(cmd_copy_to_memory, vkCmdCopyAccelerationStructureToMemoryKHR);
#undef LOAD
    if (!d.cmd_build || !d.cmd_copy_to_memory)
        clastrace::testapp::fail("no VK_KHR_acceleration_structure");
}

// Every buffer can also be built from and hold structures (host-visible coherent, mapped, zeros).
Buffer make_buffer(Device& d, VkDeviceSize size) {
    return d.makeBuffer(size, VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_BIT_KHR |
                                  VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_STORAGE_BIT_KHR);
}

// Everything between commands: copies and builds made visible to the builds and copies after.
void barrier(VkCommandBuffer cb) {
    VkMemoryBarrier b{VK_STRUCTURE_TYPE_MEMORY_BARRIER};
    b.srcAccessMask = VK_ACCESS_TRANSFER_WRITE_BIT | VK_ACCESS_ACCELERATION_STRUCTURE_WRITE_BIT_KHR;
    b.dstAccessMask = VK_ACCESS_ACCELERATION_STRUCTURE_READ_BIT_KHR |
                      VK_ACCESS_ACCELERATION_STRUCTURE_WRITE_BIT_KHR | VK_ACCESS_TRANSFER_READ_BIT |
                      VK_ACCESS_SHADER_READ_BIT;
    const VkPipelineStageFlags stages =
        VK_PIPELINE_STAGE_TRANSFER_BIT | VK_PIPELINE_STAGE_ACCELERATION_STRUCTURE_BUILD_BIT_KHR;
    vkCmdPipelineBarrier(cb, stages, stages, 0, 1, &b, 0, nullptr, 0, nullptr);
}

// The layout of the build-input buffer (and of the staging buffer it is copied from).
constexpr VkDeviceSize kVertices = 0, kIndices = 64, kAabbs = 128, kTransform = 192,
                       kInputBytes = 256;
const float kQuad[4][3] = {{-1, -1, 2}, {1, -1, 2}, {1, 1, 2}, {-1, 1, 2}};
const float kMovedQuad[4][3] = {{-1, -1, 3}, {1, -1, 3}, {1, 1, 3}, {-1, 1, 3}};
const uint32_t kQuadIndices[6] = {0, 1, 2, 0, 2, 3};
const float kBoxes[2][6] = {{-3, -1, 4, -2, 1, 5}, {2, -1, 4, 3, 1, 5}};
const float kTransform3x4[12] = {1, 0, 0, 0.5f, 0, 1, 0, 0, 0, 0, 1, 0};

struct Structure {
    VkAccelerationStructureKHR handle = VK_NULL_HANDLE;
    VkDeviceAddress address = 0;
    VkDeviceSize offset = 0, size = 0;
};

Structure create_structure(const Device& d, const Buffer& storage, VkDeviceSize& used,
                           VkDeviceSize size, VkAccelerationStructureTypeKHR type) {
    Structure s;
    s.offset = used;
    s.size = size;
    used = (used + size + 255) / 256 * 256;
    VkAccelerationStructureCreateInfoKHR info{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_CREATE_INFO_KHR};
    info.buffer = storage.buffer;
    info.offset = s.offset;
    info.size = size;
    info.type = type;
    CHECK(d.create_structure(d.device, &info, nullptr, &s.handle));
    VkAccelerationStructureDeviceAddressInfoKHR address{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_DEVICE_ADDRESS_INFO_KHR, nullptr, s.handle};
    s.address = d.structure_address(d.device, &address);
    return s;
}

VkAccelerationStructureBuildSizesInfoKHR sizes_of(
    const Device& d, const VkAccelerationStructureBuildGeometryInfoKHR& info, uint32_t primitives) {
    VkAccelerationStructureBuildSizesInfoKHR sizes{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_BUILD_SIZES_INFO_KHR};
    d.build_sizes(d.device, VK_ACCELERATION_STRUCTURE_BUILD_TYPE_DEVICE_KHR, &info, &primitives,
                  &sizes);
    return sizes;
}

uint64_t id(const void* handle) { return uint64_t(reinterpret_cast<uintptr_t>(handle)); }

}  // namespace

int main(int argc, char** argv) {
    if (argc != 2) {
        std::fprintf(stderr, "usage: khr_build_app OUT.json\n");
        return 2;
    }
    Device d;
    create_device(d);
    Buffer staging = make_buffer(d, kInputBytes), input = make_buffer(d, kInputBytes);
    Buffer storage = make_buffer(d, 1 << 20), scratch = make_buffer(d, 1 << 20);
    Buffer instances = make_buffer(d, 2 * sizeof(VkAccelerationStructureInstanceKHR));
    std::memcpy(staging.mapped + kVertices, kQuad, sizeof kQuad);
    std::memcpy(staging.mapped + kIndices, kQuadIndices, sizeof kQuadIndices);
    std::memcpy(staging.mapped + kAabbs, kBoxes, sizeof kBoxes);
    std::memcpy(staging.mapped + kTransform, kTransform3x4, sizeof kTransform3x4);

    // The two bottom levels.
    VkAccelerationStructureGeometryKHR triangles{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_GEOMETRY_KHR};
    triangles.geometryType = VK_GEOMETRY_TYPE_TRIANGLES_KHR;
    triangles.flags = VK_GEOMETRY_OPAQUE_BIT_KHR;
    auto& t = triangles.geometry.triangles;
    t.sType = VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_GEOMETRY_TRIANGLES_DATA_KHR;
    t.vertexFormat = VK_FORMAT_R32G32B32_SFLOAT;
    t.vertexData.deviceAddress = input.address + kVertices;
    t.vertexStride = 12;
    t.maxVertex = 3;
    t.indexType = VK_INDEX_TYPE_UINT32;
    t.indexData.deviceAddress = input.address + kIndices;
    t.transformData.deviceAddress = input.address + kTransform;
    VkAccelerationStructureGeometryKHR boxes{VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_GEOMETRY_KHR};
    boxes.geometryType = VK_GEOMETRY_TYPE_AABBS_KHR;
    boxes.geometry.aabbs.sType = VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_GEOMETRY_AABBS_DATA_KHR;
    boxes.geometry.aabbs.data.deviceAddress = input.address + kAabbs;
    boxes.geometry.aabbs.stride = 24;

    VkAccelerationStructureBuildGeometryInfoKHR blas[2] = {
        {VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_BUILD_GEOMETRY_INFO_KHR},
        {VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_BUILD_GEOMETRY_INFO_KHR}};
    blas[0].type = blas[1].type = VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR;
    blas[0].flags = VK_BUILD_ACCELERATION_STRUCTURE_ALLOW_COMPACTION_BIT_KHR |
                    VK_BUILD_ACCELERATION_STRUCTURE_ALLOW_UPDATE_BIT_KHR;
    blas[1].flags = VK_BUILD_ACCELERATION_STRUCTURE_PREFER_FAST_TRACE_BIT_KHR;
    blas[0].mode = blas[1].mode = VK_BUILD_ACCELERATION_STRUCTURE_MODE_BUILD_KHR;
    blas[0].geometryCount = blas[1].geometryCount = 1;
    blas[0].pGeometries = &triangles;
    blas[1].pGeometries = &boxes;
    const auto triangle_sizes = sizes_of(d, blas[0], 2);
    const auto box_sizes = sizes_of(d, blas[1], 2);
    VkDeviceSize used = 0;
    Structure triangle_blas =
        create_structure(d, storage, used, triangle_sizes.accelerationStructureSize,
                         VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR);
    Structure box_blas = create_structure(d, storage, used, box_sizes.accelerationStructureSize,
                                          VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR);
    blas[0].dstAccelerationStructure = triangle_blas.handle;
    blas[1].dstAccelerationStructure = box_blas.handle;
    blas[0].scratchData.deviceAddress = scratch.address;
    blas[1].scratchData.deviceAddress = scratch.address + (256 << 10);
    const VkAccelerationStructureBuildRangeInfoKHR triangle_range{2, 0, 0, 0};
    const VkAccelerationStructureBuildRangeInfoKHR box_range{2, 0, 0, 0};
    const VkAccelerationStructureBuildRangeInfoKHR* blas_ranges[2] = {&triangle_range, &box_range};

    // The top level over one instance of each.
    VkAccelerationStructureInstanceKHR instance_data[2]{};
    const Structure* targets[2] = {&triangle_blas, &box_blas};
    for (uint32_t i = 0; i < 2; ++i) {
        auto& m = instance_data[i].transform.matrix;
        m[0][0] = m[1][1] = m[2][2] = 1;
        m[0][3] = float(i) * 4;
        instance_data[i].instanceCustomIndex = 10 + i;
        instance_data[i].mask = 0xff;
        instance_data[i].flags = VK_GEOMETRY_INSTANCE_TRIANGLE_FACING_CULL_DISABLE_BIT_KHR;
        instance_data[i].accelerationStructureReference = targets[i]->address;
    }
    std::memcpy(instances.mapped, instance_data, sizeof instance_data);
    VkAccelerationStructureGeometryKHR instance_geometry{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_GEOMETRY_KHR};
    instance_geometry.geometryType = VK_GEOMETRY_TYPE_INSTANCES_KHR;
    instance_geometry.geometry.instances.sType =
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_GEOMETRY_INSTANCES_DATA_KHR;
    instance_geometry.geometry.instances.data.deviceAddress = instances.address;
    VkAccelerationStructureBuildGeometryInfoKHR tlas{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_BUILD_GEOMETRY_INFO_KHR};
    tlas.type = VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_KHR;
    tlas.mode = VK_BUILD_ACCELERATION_STRUCTURE_MODE_BUILD_KHR;
    tlas.geometryCount = 1;
    tlas.pGeometries = &instance_geometry;
    const auto tlas_sizes = sizes_of(d, tlas, 2);
    Structure top = create_structure(d, storage, used, tlas_sizes.accelerationStructureSize,
                                     VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_KHR);
    tlas.dstAccelerationStructure = top.handle;
    tlas.scratchData.deviceAddress = scratch.address + (512 << 10);
    const VkAccelerationStructureBuildRangeInfoKHR tlas_range{2, 0, 0, 0};
    const VkAccelerationStructureBuildRangeInfoKHR* tlas_ranges[1] = {&tlas_range};

    VkQueryPool compacted =
        d.makeQueryPool(VK_QUERY_TYPE_ACCELERATION_STRUCTURE_COMPACTED_SIZE_KHR);
    VkQueryPool serialized =
        d.makeQueryPool(VK_QUERY_TYPE_ACCELERATION_STRUCTURE_SERIALIZATION_SIZE_KHR);

    VkCommandBuffer first = d.beginCommands();
    const VkBufferCopy upload{0, 0, kInputBytes};
    vkCmdCopyBuffer(first, staging.buffer, input.buffer, 1, &upload);
    barrier(first);
    d.cmd_build(first, 2, blas, blas_ranges);
    barrier(first);
    vkCmdResetQueryPool(first, compacted, 0, 1);
    d.cmd_write_properties(first, 1, &triangle_blas.handle,
                           VK_QUERY_TYPE_ACCELERATION_STRUCTURE_COMPACTED_SIZE_KHR, compacted, 0);
    d.cmd_build(first, 1, &tlas, tlas_ranges);
    barrier(first);
    vkCmdResetQueryPool(first, serialized, 0, 1);
    d.cmd_write_properties(first, 1, &top.handle,
                           VK_QUERY_TYPE_ACCELERATION_STRUCTURE_SERIALIZATION_SIZE_KHR, serialized,
                           0);
    d.submitAndWait(first);
    const uint64_t compacted_size = d.queryResult(compacted);
    const uint64_t serialized_size = d.queryResult(serialized);

    // Compaction, serialization, and an update of the triangle BLAS from moved vertices.
    Structure compact = create_structure(d, storage, used, compacted_size,
                                         VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR);
    Buffer serial = make_buffer(d, serialized_size);
    std::memcpy(staging.mapped + kVertices, kMovedQuad, sizeof kMovedQuad);
    VkCommandBuffer second = d.beginCommands();
    VkCopyAccelerationStructureInfoKHR copy{VK_STRUCTURE_TYPE_COPY_ACCELERATION_STRUCTURE_INFO_KHR};
    copy.src = triangle_blas.handle;
    copy.dst = compact.handle;
    copy.mode = VK_COPY_ACCELERATION_STRUCTURE_MODE_COMPACT_KHR;
    d.cmd_copy(second, &copy);
    VkCopyAccelerationStructureToMemoryInfoKHR to_memory{
        VK_STRUCTURE_TYPE_COPY_ACCELERATION_STRUCTURE_TO_MEMORY_INFO_KHR};
    to_memory.src = top.handle;
    to_memory.dst.deviceAddress = serial.address;
    to_memory.mode = VK_COPY_ACCELERATION_STRUCTURE_MODE_SERIALIZE_KHR;
    d.cmd_copy_to_memory(second, &to_memory);
    const VkBufferCopy moved{kVertices, kVertices, sizeof kMovedQuad};
    vkCmdCopyBuffer(second, staging.buffer, input.buffer, 1, &moved);
    barrier(second);
    VkAccelerationStructureBuildGeometryInfoKHR update = blas[0];
    update.mode = VK_BUILD_ACCELERATION_STRUCTURE_MODE_UPDATE_KHR;
    update.srcAccelerationStructure = triangle_blas.handle;
    update.dstAccelerationStructure = triangle_blas.handle;
    d.cmd_build(second, 1, &update, blas_ranges);
    d.submitAndWait(second);

    json out;
    out["input"] = {{"buffer", id(input.buffer)}, {"address", input.address}};
    out["instances"] = {{"buffer", id(instances.buffer)},
                        {"address", instances.address},
                        {"bytes", hex(instance_data, sizeof instance_data)}};
    out["bytes"] = {{"vertices", hex(kQuad, sizeof kQuad)},
                    {"movedVertices", hex(kMovedQuad, sizeof kMovedQuad)},
                    {"indices", hex(kQuadIndices, sizeof kQuadIndices)},
                    {"aabbs", hex(kBoxes, sizeof kBoxes)},
                    {"transform", hex(kTransform3x4, sizeof kTransform3x4)}};
    out["offsets"] = {{"vertices", kVertices},
                      {"indices", kIndices},
                      {"aabbs", kAabbs},
                      {"transform", kTransform}};
    auto structure_json = [](const Structure& s) {
        return json{{"handle", id(s.handle)},
                    {"address", s.address},
                    {"offset", s.offset},
                    {"size", s.size}};
    };
    out["triangleBlas"] = structure_json(triangle_blas);
    out["boxBlas"] = structure_json(box_blas);
    out["tlas"] = structure_json(top);
    out["compact"] = structure_json(compact);
    out["storage"] = id(storage.buffer);
    out["scratch"] = scratch.address;
    out["serial"] = serial.address;
    out["queryPools"] = {{"compacted", id(compacted)}, {"serialized", id(serialized)}};
    out["compactedSize"] = compacted_size;
    out["serializedSize"] = serialized_size;
    out["sizes"] = {{"triangle", triangle_sizes.accelerationStructureSize},
                    {"box", box_sizes.accelerationStructureSize},
                    {"tlas", tlas_sizes.accelerationStructureSize}};
    std::ofstream(argv[1]) << out.dump(1);
    vkDeviceWaitIdle(d.device);
    std::printf("ok\n");
    return 0;
}
