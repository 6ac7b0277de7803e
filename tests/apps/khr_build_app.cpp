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

// The program's buffers, build infos and structures. The infos point into it (geometries,
// ranges): it is filled in place and never moved.
struct Scene {
    Buffer staging, input, storage, scratch, instances, serial;
    VkDeviceSize used = 0;  // bytes of `storage` taken by structures
    VkAccelerationStructureGeometryKHR triangles{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_GEOMETRY_KHR};
    VkAccelerationStructureGeometryKHR boxes{VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_GEOMETRY_KHR};
    VkAccelerationStructureGeometryKHR instance_geometry{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_GEOMETRY_KHR};
    VkAccelerationStructureBuildGeometryInfoKHR blas[2] = {
        {VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_BUILD_GEOMETRY_INFO_KHR},
        {VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_BUILD_GEOMETRY_INFO_KHR}};
    VkAccelerationStructureBuildGeometryInfoKHR tlas{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_BUILD_GEOMETRY_INFO_KHR};
    VkAccelerationStructureBuildSizesInfoKHR triangle_sizes{}, box_sizes{}, tlas_sizes{};
    VkAccelerationStructureBuildRangeInfoKHR triangle_range{2, 0, 0, 0}, box_range{2, 0, 0, 0},
        tlas_range{2, 0, 0, 0};
    const VkAccelerationStructureBuildRangeInfoKHR* blas_ranges[2] = {&triangle_range, &box_range};
    const VkAccelerationStructureBuildRangeInfoKHR* tlas_ranges[1] = {&tlas_range};
    VkAccelerationStructureInstanceKHR instance_data[2]{};
    Structure triangle_blas, box_blas, top, compact;
    VkQueryPool compacted = VK_NULL_HANDLE, serialized = VK_NULL_HANDLE;
    uint64_t compacted_size = 0, serialized_size = 0;
};

void make_buffers(Device& d, Scene& s) {
    s.staging = make_buffer(d, kInputBytes);
    s.input = make_buffer(d, kInputBytes);
    s.storage = make_buffer(d, 1 << 20);
    s.scratch = make_buffer(d, 1 << 20);
    s.instances = make_buffer(d, 2 * sizeof(VkAccelerationStructureInstanceKHR));
    std::memcpy(s.staging.mapped + kVertices, kQuad, sizeof kQuad);
    std::memcpy(s.staging.mapped + kIndices, kQuadIndices, sizeof kQuadIndices);
    std::memcpy(s.staging.mapped + kAabbs, kBoxes, sizeof kBoxes);
    std::memcpy(s.staging.mapped + kTransform, kTransform3x4, sizeof kTransform3x4);
}

void describe_geometries(Scene& s) {
    s.triangles.geometryType = VK_GEOMETRY_TYPE_TRIANGLES_KHR;
    s.triangles.flags = VK_GEOMETRY_OPAQUE_BIT_KHR;
    auto& t = s.triangles.geometry.triangles;
    t.sType = VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_GEOMETRY_TRIANGLES_DATA_KHR;
    t.vertexFormat = VK_FORMAT_R32G32B32_SFLOAT;
    t.vertexData.deviceAddress = s.input.address + kVertices;
    t.vertexStride = 12;
    t.maxVertex = 3;
    t.indexType = VK_INDEX_TYPE_UINT32;
    t.indexData.deviceAddress = s.input.address + kIndices;
    t.transformData.deviceAddress = s.input.address + kTransform;
    s.boxes.geometryType = VK_GEOMETRY_TYPE_AABBS_KHR;
    s.boxes.geometry.aabbs.sType = VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_GEOMETRY_AABBS_DATA_KHR;
    s.boxes.geometry.aabbs.data.deviceAddress = s.input.address + kAabbs;
    s.boxes.geometry.aabbs.stride = 24;
}

// The two bottom levels: a triangle one (allowing compaction and update) and an AABB one.
void describe_bottom_levels(const Device& d, Scene& s) {
    auto& blas = s.blas;
    blas[0].type = blas[1].type = VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR;
    blas[0].flags = VK_BUILD_ACCELERATION_STRUCTURE_ALLOW_COMPACTION_BIT_KHR |
                    VK_BUILD_ACCELERATION_STRUCTURE_ALLOW_UPDATE_BIT_KHR;
    blas[1].flags = VK_BUILD_ACCELERATION_STRUCTURE_PREFER_FAST_TRACE_BIT_KHR;
    blas[0].mode = blas[1].mode = VK_BUILD_ACCELERATION_STRUCTURE_MODE_BUILD_KHR;
    blas[0].geometryCount = blas[1].geometryCount = 1;
    blas[0].pGeometries = &s.triangles;
    blas[1].pGeometries = &s.boxes;
    s.triangle_sizes = sizes_of(d, blas[0], 2);
    s.box_sizes = sizes_of(d, blas[1], 2);
    s.triangle_blas =
        create_structure(d, s.storage, s.used, s.triangle_sizes.accelerationStructureSize,
                         VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR);
    s.box_blas = create_structure(d, s.storage, s.used, s.box_sizes.accelerationStructureSize,
                                  VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR);
    blas[0].dstAccelerationStructure = s.triangle_blas.handle;
    blas[1].dstAccelerationStructure = s.box_blas.handle;
    blas[0].scratchData.deviceAddress = s.scratch.address;
    blas[1].scratchData.deviceAddress = s.scratch.address + (256 << 10);
}

// The top level over one instance of each bottom level.
void describe_top_level(const Device& d, Scene& s) {
    const Structure* targets[2] = {&s.triangle_blas, &s.box_blas};
    for (uint32_t i = 0; i < 2; ++i) {
        auto& m = s.instance_data[i].transform.matrix;
        m[0][0] = m[1][1] = m[2][2] = 1;
        m[0][3] = float(i) * 4;
        s.instance_data[i].instanceCustomIndex = 10 + i;
        s.instance_data[i].mask = 0xff;
        s.instance_data[i].flags = VK_GEOMETRY_INSTANCE_TRIANGLE_FACING_CULL_DISABLE_BIT_KHR;
        s.instance_data[i].accelerationStructureReference = targets[i]->address;
    }
    std::memcpy(s.instances.mapped, s.instance_data, sizeof s.instance_data);
    s.instance_geometry.geometryType = VK_GEOMETRY_TYPE_INSTANCES_KHR;
    s.instance_geometry.geometry.instances.sType =
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_GEOMETRY_INSTANCES_DATA_KHR;
    s.instance_geometry.geometry.instances.data.deviceAddress = s.instances.address;
    s.tlas.type = VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_KHR;
    s.tlas.mode = VK_BUILD_ACCELERATION_STRUCTURE_MODE_BUILD_KHR;
    s.tlas.geometryCount = 1;
    s.tlas.pGeometries = &s.instance_geometry;
    s.tlas_sizes = sizes_of(d, s.tlas, 2);
    s.top = create_structure(d, s.storage, s.used, s.tlas_sizes.accelerationStructureSize,
                             VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_KHR);
    s.tlas.dstAccelerationStructure = s.top.handle;
    s.tlas.scratchData.deviceAddress = s.scratch.address + (512 << 10);
}

// Submission 1: the inputs copied in, both bottom levels, their compacted size, the top level
// and its serialization size.
void build_all(Device& d, Scene& s) {
    s.compacted = d.makeQueryPool(VK_QUERY_TYPE_ACCELERATION_STRUCTURE_COMPACTED_SIZE_KHR);
    s.serialized = d.makeQueryPool(VK_QUERY_TYPE_ACCELERATION_STRUCTURE_SERIALIZATION_SIZE_KHR);
    VkCommandBuffer first = d.beginCommands();
    const VkBufferCopy upload{0, 0, kInputBytes};
    vkCmdCopyBuffer(first, s.staging.buffer, s.input.buffer, 1, &upload);
    barrier(first);
    d.cmd_build(first, 2, s.blas, s.blas_ranges);
    barrier(first);
    vkCmdResetQueryPool(first, s.compacted, 0, 1);
    d.cmd_write_properties(first, 1, &s.triangle_blas.handle,
                           VK_QUERY_TYPE_ACCELERATION_STRUCTURE_COMPACTED_SIZE_KHR, s.compacted, 0);
    d.cmd_build(first, 1, &s.tlas, s.tlas_ranges);
    barrier(first);
    vkCmdResetQueryPool(first, s.serialized, 0, 1);
    d.cmd_write_properties(first, 1, &s.top.handle,
                           VK_QUERY_TYPE_ACCELERATION_STRUCTURE_SERIALIZATION_SIZE_KHR,
                           s.serialized, 0);
    d.submitAndWait(first);
    s.compacted_size = d.queryResult(s.compacted);
    s.serialized_size = d.queryResult(s.serialized);
}

// Submission 2: compaction, serialization, and an update of the triangle BLAS from moved
// vertices.
void compact_serialize_update(Device& d, Scene& s) {
    s.compact = create_structure(d, s.storage, s.used, s.compacted_size,
                                 VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR);
    s.serial = make_buffer(d, s.serialized_size);
    std::memcpy(s.staging.mapped + kVertices, kMovedQuad, sizeof kMovedQuad);
    VkCommandBuffer second = d.beginCommands();
    VkCopyAccelerationStructureInfoKHR copy{VK_STRUCTURE_TYPE_COPY_ACCELERATION_STRUCTURE_INFO_KHR};
    copy.src = s.triangle_blas.handle;
    copy.dst = s.compact.handle;
    copy.mode = VK_COPY_ACCELERATION_STRUCTURE_MODE_COMPACT_KHR;
    d.cmd_copy(second, &copy);
    VkCopyAccelerationStructureToMemoryInfoKHR to_memory{
        VK_STRUCTURE_TYPE_COPY_ACCELERATION_STRUCTURE_TO_MEMORY_INFO_KHR};
    to_memory.src = s.top.handle;
    to_memory.dst.deviceAddress = s.serial.address;
    to_memory.mode = VK_COPY_ACCELERATION_STRUCTURE_MODE_SERIALIZE_KHR;
    d.cmd_copy_to_memory(second, &to_memory);
    const VkBufferCopy moved{kVertices, kVertices, sizeof kMovedQuad};
    vkCmdCopyBuffer(second, s.staging.buffer, s.input.buffer, 1, &moved);
    barrier(second);
    VkAccelerationStructureBuildGeometryInfoKHR update = s.blas[0];
    update.mode = VK_BUILD_ACCELERATION_STRUCTURE_MODE_UPDATE_KHR;
    update.srcAccelerationStructure = s.triangle_blas.handle;
    update.dstAccelerationStructure = s.triangle_blas.handle;
    d.cmd_build(second, 1, &update, s.blas_ranges);
    d.submitAndWait(second);
}

json structure_json(const Structure& s) {
    return json{{"handle", id(s.handle)},
                {"address", s.address},
                {"offset", s.offset},
                {"size", s.size}};
}

json scene_json(const Scene& s) {
    json out;
    out["input"] = {{"buffer", id(s.input.buffer)}, {"address", s.input.address}};
    out["instances"] = {{"buffer", id(s.instances.buffer)},
                        {"address", s.instances.address},
                        {"bytes", hex(s.instance_data, sizeof s.instance_data)}};
    out["bytes"] = {{"vertices", hex(kQuad, sizeof kQuad)},
                    {"movedVertices", hex(kMovedQuad, sizeof kMovedQuad)},
                    {"indices", hex(kQuadIndices, sizeof kQuadIndices)},
                    {"aabbs", hex(kBoxes, sizeof kBoxes)},
                    {"transform", hex(kTransform3x4, sizeof kTransform3x4)}};
    out["offsets"] = {{"vertices", kVertices},
                      {"indices", kIndices},
                      {"aabbs", kAabbs},
                      {"transform", kTransform}};
    out["triangleBlas"] = structure_json(s.triangle_blas);
    out["boxBlas"] = structure_json(s.box_blas);
    out["tlas"] = structure_json(s.top);
    out["compact"] = structure_json(s.compact);
    out["storage"] = id(s.storage.buffer);
    out["scratch"] = s.scratch.address;
    out["serial"] = s.serial.address;
    out["queryPools"] = {{"compacted", id(s.compacted)}, {"serialized", id(s.serialized)}};
    out["compactedSize"] = s.compacted_size;
    out["serializedSize"] = s.serialized_size;
    out["sizes"] = {{"triangle", s.triangle_sizes.accelerationStructureSize},
                    {"box", s.box_sizes.accelerationStructureSize},
                    {"tlas", s.tlas_sizes.accelerationStructureSize}};
    return out;
}

}  // namespace

int main(int argc, char** argv) {
    if (argc != 2) {
        std::fprintf(stderr, "usage: khr_build_app OUT.json\n");
        return 2;
    }
    Device d;
    create_device(d);
    Scene s;
    make_buffers(d, s);
    describe_geometries(s);
    describe_bottom_levels(d, s);
    describe_top_level(d, s);
    build_all(d, s);
    compact_serialize_update(d, s);
    std::ofstream(argv[1]) << scene_json(s).dump(1);
    vkDeviceWaitIdle(d.device);
    std::printf("ok\n");
    return 0;
}
