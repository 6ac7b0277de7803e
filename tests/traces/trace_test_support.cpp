// SPDX-License-Identifier: Apache-2.0
#include "trace_test_support.h"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <random>

namespace clastrace::traces::testing {

namespace {

// The damage tests check every rule the reader knows, the content-key check included.
const TraceReaderOptions kVerifyEverything{.verify_content_keys = true};
template <class T>
fbs::RecordT record(T body) {
    fbs::RecordT r;
    r.body.Set(std::move(body));
    return r;
}

std::unique_ptr<fbs::DependencyT> dependency(uint64_t salt) {
    auto d = std::make_unique<fbs::DependencyT>();
    d->dependency_flags = 1;
    d->memory_barriers.emplace_back(0x1000 + salt, 0x2000, 0x02000000, 0x200000);
    d->buffer_barriers.emplace_back(0x1000, 0x1000, 0x02000000, 0x1, 7, 8, 0xb0f + salt, 64,
                                    ~uint64_t{0});
    d->image_barrier_count = 2;
    return d;
}

std::unique_ptr<fbs::ClusterInputInfoT> cluster_input(int which) {
    auto in = std::make_unique<fbs::ClusterInputInfoT>();
    in->max_acceleration_structure_count = 1000 + which;
    in->flags = 0x1000 | 0x1;
    in->op_type = static_cast<uint32_t>(which == 0 ? 2 : which == 1 ? 1 : 0);
    in->op_mode = static_cast<uint32_t>(which);
    in->unrecorded_next_stypes = {1000569099u};
    if (which == 0) {
        fbs::TriangleClusterInputT t;
        t.vertex_format = 106;
        t.max_geometry_index_value = 3;
        t.max_cluster_unique_geometry_count = 2;
        t.max_cluster_triangle_count = 256;
        t.max_cluster_vertex_count = 256;
        t.max_total_triangle_count = 1 << 20;
        t.max_total_vertex_count = 1 << 20;
        t.min_position_truncate_bit_count = 5;
        in->op_input.Set(std::move(t));
    } else if (which == 1) {
        fbs::ClustersBottomLevelInputT b;
        b.max_total_cluster_count = 4096;
        b.max_cluster_count_per_acceleration_structure = 512;
        in->op_input.Set(std::move(b));
    } else {
        fbs::MoveObjectsInputT m;
        m.type = 1;
        m.no_move_overlap = true;
        m.max_moved_bytes = 1ull << 33;
        in->op_input.Set(std::move(m));
    }
    return in;
}
}  // namespace

fbs::TraceHeaderT test_header() {
    fbs::TraceHeaderT h;
    h.device = std::make_unique<fbs::DeviceInfoT>();
    h.device->name = "Test GPU";
    h.device->vendor_id = 0x10de;
    h.device->device_id = 0x1234;
    h.device->driver_version = 42;
    h.device->api_version = (1u << 22) | (4u << 12);
    h.device->memory_types = {fbs::MemoryType(1, 0), fbs::MemoryType(6, 1)};
    h.device->cluster_features = std::make_unique<fbs::ClusterFeaturesT>();
    h.device->cluster_features->cluster_acceleration_structure_supported = true;
    h.device->cluster_properties = std::make_unique<fbs::ClusterPropertiesT>();
    h.device->cluster_properties->max_vertices_per_cluster = 256;
    h.device->cluster_properties->max_triangles_per_cluster = 256;
    h.device->cluster_properties->max_cluster_geometry_index = 16777215;
    h.capture = std::make_unique<fbs::CaptureSettingsT>();
    h.capture->application_name = "trace tests";
    return h;
}


// The KHR build's bottom level: R32G32B32_SFLOAT vertices, UINT32 indices.
static std::unique_ptr<fbs::AccelerationStructureBuildInfoKHRT> khr_bottom_level_info() {
    auto triangles = std::make_unique<fbs::GeometryKHRT>();
    triangles->geometry_type = 0;  // VK_GEOMETRY_TYPE_TRIANGLES_KHR
    triangles->flags = 1;          // OPAQUE
    triangles->triangles =
        std::make_unique<fbs::GeometryTrianglesKHR>(106, 0x7000, 12, 35, 1, 0x7800, 0);
    auto bottom = std::make_unique<fbs::AccelerationStructureBuildInfoKHRT>();
    bottom->type = 1;  // BOTTOM_LEVEL
    bottom->flags = 2 | 8;
    bottom->dst = 0xa51;
    bottom->scratch_address = 0x9000;
    bottom->geometries.push_back(std::move(triangles));
    bottom->ranges = {fbs::BuildRangeInfoKHR(12, 0, 0, 0)};
    bottom->unrecorded_next_stypes = {1000150013};
    return bottom;
}

// The KHR build's top level: an update of 0xa52, its ranges read indirectly.
static std::unique_ptr<fbs::AccelerationStructureBuildInfoKHRT> khr_indirect_top_level_info() {
    auto instances = std::make_unique<fbs::GeometryKHRT>();
    instances->geometry_type = 2;  // INSTANCES
    instances->instances = std::make_unique<fbs::GeometryInstancesKHR>(false, 0xb000);
    auto top = std::make_unique<fbs::AccelerationStructureBuildInfoKHRT>();
    top->type = 0;  // TOP_LEVEL
    top->mode = 1;  // UPDATE
    top->src = 0xa52;
    top->dst = 0xa52;
    top->scratch_address = 0x9400;
    top->geometries.push_back(std::move(instances));
    top->ranges = {fbs::BuildRangeInfoKHR(3, 64, 0, 0)};
    top->indirect_address = 0xc000;
    top->indirect_stride = 16;
    top->max_primitive_counts = {8};
    return top;
}

static void append_khr_build(std::vector<fbs::RecordT>& out) {
    fbs::CmdBuildAccelerationStructuresKHRT r;
    r.command_buffer = 0xcb2;
    r.indirect = true;
    r.infos.push_back(khr_bottom_level_info());
    r.infos.push_back(khr_indirect_top_level_info());
    r.inputs = {fbs::MemorySnapshot(0xb0, 0, 0xb000, 192, 0x1234)};
    r.outputs = {fbs::MemorySnapshot(0xa0, 256, 0xa100, 1024, 0x5678)};
    out.push_back(record(r));
}

// A compacting copy, then a serialization of the copy.
static void append_structure_copies(std::vector<fbs::RecordT>& out) {
    {
        fbs::CmdCopyAccelerationStructureT r;
        r.command_buffer = 0xcb2;
        r.api = 1;
        r.src = 0xa51;
        r.dst = 0xa53;
        r.mode = 1;  // COMPACT
        out.push_back(record(r));
    }
    {
        fbs::CmdCopyAccelerationStructureToMemoryT r;
        r.command_buffer = 0xcb2;
        r.src = 0xa53;
        r.dst_address = 0xd000;
        r.mode = 2;  // SERIALIZE
        out.push_back(record(r));
    }
}

// A compacted-size query and its answers, then a build-size query.
static void append_property_queries(std::vector<fbs::RecordT>& out) {
    {
        fbs::CmdWriteAccelerationStructuresPropertiesT r;
        r.command_buffer = 0xcb2;
        r.api = 1;
        r.acceleration_structures = {0xa51, 0xa52};
        r.query_type = 1000150000;  // ACCELERATION_STRUCTURE_COMPACTED_SIZE_KHR
        r.query_pool = 0x9001;
        r.first_query = 4;
        out.push_back(record(r));
    }
    {
        fbs::QueryPoolResultsT r;
        r.query_pool = 0x9001;
        r.first_query = 4;
        r.values = {896, 1536};
        out.push_back(record(r));
    }
    {
        fbs::GetAccelerationStructureBuildSizesKHRT r;
        r.build_type = 1;  // DEVICE
        r.info = std::make_unique<fbs::AccelerationStructureBuildInfoKHRT>();
        r.info->type = 1;
        r.max_primitive_counts = {12};
        r.acceleration_structure_size = 4096;
        r.update_scratch_size = 512;
        r.build_scratch_size = 2048;
        out.push_back(record(r));
    }
}

// A ray-query dispatch, rays traced indirectly, and the dispatch's exact writes.
static void append_shader_uses(std::vector<fbs::RecordT>& out) {
    {
        fbs::CmdDispatchT r;
        r.command_buffer = 0xcb3;
        r.pipeline = 0x92;
        r.group_count_x = 16;
        r.ray_query = true;
        r.acceleration_structures = {fbs::AccelerationStructureBinding(0, 1, 0, 0, 0xa52, 0xa200),
                                     fbs::AccelerationStructureBinding(0, 0, 0, 3, 0, 0xa300)};
        out.push_back(record(r));
    }
    {
        fbs::CmdTraceRaysT r;
        r.command_buffer = 0xcb3;
        r.pipeline = 0x93;
        r.entry_point = "vkCmdTraceRaysIndirect2KHR";
        r.indirect_address = 0xe000;
        r.shader_binding_tables = {fbs::StridedDeviceAddressRegion(0xf000, 64, 64),
                                   fbs::StridedDeviceAddressRegion(0xf040, 32, 64),
                                   {},
                                   {}};
        r.acceleration_structures = {fbs::AccelerationStructureBinding(1, 0, 2, 1, 0xa52, 0xa200)};
        r.inputs = {fbs::MemorySnapshot(0xe0, 0, 0xe000, 104, 0x9abc)};
        out.push_back(record(r));
    }
    {
        fbs::DeviceAddressWritesT r;
        r.submission = 7;
        r.command_buffer = 0xcb3;
        r.command_index = 2;
        r.writes = {fbs::MemorySnapshot(0xb0, 64, 0xb040, 48, 0xdef0)};
        r.compared_bytes = 1 << 20;
        out.push_back(record(r));
    }
}

// Format 1.4: KHR builds (a bottom level from indexed triangles, an indirect top level), the
// copies, property queries and their answers, a size query, a ray-query dispatch, rays traced
// indirectly, and the exact writes of a dispatch.
static void append_acceleration_structure_use_records(std::vector<fbs::RecordT>& out) {
    append_khr_build(out);
    append_structure_copies(out);
    append_property_queries(out);
    append_shader_uses(out);
}

namespace {

// The writer and the two byte strings every record's snapshots are cut from.
struct EveryKindBytes {
    TraceWriter& writer;
    std::vector<uint8_t> a = std::vector<uint8_t>(300), b = std::vector<uint8_t>(77);

    explicit EveryKindBytes(TraceWriter& w) : writer(w) {
        for (size_t i = 0; i < a.size(); ++i) a[i] = static_cast<uint8_t>(i * 7);
        for (size_t i = 0; i < b.size(); ++i) b[i] = static_cast<uint8_t>(255 - i);
    }
    fbs::MemorySnapshot snap(uint64_t address, const std::vector<uint8_t>& bytes) {
        fbs::MemorySnapshot s;
        EXPECT_FALSE(
            writer.snapshot(0xb0f, address & 0xfff, address, bytes.data(), bytes.size(), &s));
        return s;
    }
};

// The memory, buffer and acceleration-structure object records.
void append_memory_and_object_records(std::vector<fbs::RecordT>& out, EveryKindBytes& bytes) {
    auto snap = [&](uint64_t address, const std::vector<uint8_t>& v) {
        return bytes.snap(address, v);
    };
    const std::vector<uint8_t>& a = bytes.a;
    {
        fbs::MemoryAllocateT r;
        r.memory = 0x10;
        r.size = 1 << 20;
        r.memory_type_index = 1;
        r.allocate_flags = 2;
        r.opaque_capture_address = 0x5000;
        out.push_back(record(r));
    }
    {
        fbs::MemoryFreeT r;
        r.memory = 0x10;
        out.push_back(record(r));
    }
    {
        fbs::MemoryObservationT r;
        r.memory = 0x10;
        r.memory_offset = 64;
        r.reason = 1;
        r.snapshots = {snap(0x7000, a)};
        out.push_back(record(r));
    }
    {
        fbs::BufferCreateT r;
        r.buffer = 0xb0f;
        r.size = 4096;
        r.usage = 0x20000 | (1ull << 40);
        r.create_flags = 0x10;
        r.sharing_mode = 1;
        r.queue_family_indices = {0, 2};
        out.push_back(record(r));
    }
    {
        fbs::BufferBindMemoryT r;
        r.buffer = 0xb0f;
        r.memory = 0x10;
        r.memory_offset = 256;
        r.device_address = 0x7000;
        out.push_back(record(r));
    }
    {
        fbs::BufferDestroyT r;
        r.buffer = 0xb0f;
        out.push_back(record(r));
    }
    {
        fbs::AccelerationStructureCreateT r;
        r.acceleration_structure = 0xa5;
        r.api = 1;
        r.type = 0;
        r.buffer = 0xb0f;
        r.offset = 512;
        r.size = 8192;
        r.create_flags = 1;
        r.compacted_size = 99;
        r.device_address = 0x7200;
        r.info = std::make_unique<fbs::AccelerationStructureInfoNVT>();
        r.info->type = 1;
        r.info->instance_count = 3;
        out.push_back(record(std::move(r)));
    }
    {
        fbs::AccelerationStructureBindMemoryT r;
        r.acceleration_structure = 0xa5;
        r.memory = 0x10;
        r.memory_offset = 1024;
        out.push_back(record(r));
    }
    {
        fbs::AccelerationStructureDestroyT r;
        r.acceleration_structure = 0xa5;
        out.push_back(record(r));
    }
    {
        fbs::AccelerationStructureMemoryRequirementsNVT r;
        r.acceleration_structure = 0xa5;
        r.type = 2;
        r.size = 4096;
        r.alignment = 256;
        r.memory_type_bits = 3;
        out.push_back(record(r));
    }
}

// Command buffers, barriers and events.
void append_command_buffer_and_sync_records(std::vector<fbs::RecordT>& out) {
    {
        fbs::CommandBufferBeginT r;
        r.command_buffer = 0xcb;
        r.flags = 1;
        r.level = 1;
        r.restatement = 2;
        out.push_back(record(r));
    }
    {
        fbs::CommandBufferEndT r;
        r.command_buffer = 0xcb;
        out.push_back(record(r));
    }
    {
        fbs::CommandBufferResetT r;
        r.command_buffer = 0xcb;
        r.flags = 1;
        r.command_pool = 0xc0;
        out.push_back(record(r));
    }
    {
        fbs::CmdPipelineBarrierT r;
        r.command_buffer = 0xcb;
        r.version = 1;
        r.src_stage_mask = 0x1000;
        r.dst_stage_mask = 0x02000000;
        r.dependency = dependency(1);
        out.push_back(record(std::move(r)));
    }
    {
        fbs::CmdSetEventT r;
        r.command_buffer = 0xcb;
        r.event = 0xe1;
        r.version = 2;
        r.stage_mask = 0;
        r.dependency = dependency(2);
        out.push_back(record(std::move(r)));
    }
    {
        fbs::CmdResetEventT r;
        r.command_buffer = 0xcb;
        r.event = 0xe1;
        r.version = 1;
        r.stage_mask = 0x1000;
        out.push_back(record(r));
    }
    {
        fbs::CmdWaitEventsT r;
        r.command_buffer = 0xcb;
        r.version = 2;
        r.events = {0xe1, 0xe2};
        r.src_stage_mask = 4;
        r.dst_stage_mask = 8;
        r.dependencies.push_back(dependency(3));
        r.dependencies.push_back(dependency(4));
        out.push_back(record(std::move(r)));
    }
    {
        fbs::HostEventOpT r;
        r.event = 0xe1;
        r.op = 2;
        r.result = 3;
        out.push_back(record(r));
    }
}

// The NV build's geometries: triangles (with an unused AABB part) and AABBs.
std::unique_ptr<fbs::AccelerationStructureInfoNVT> nv_bottom_level_info() {
    auto info = std::make_unique<fbs::AccelerationStructureInfoNVT>();
    info->type = 1;
    info->flags = 0x4;
    info->instance_count = 0;
    auto tri = std::make_unique<fbs::GeometryNVT>();
    tri->geometry_type = 0;
    tri->flags = 1;
    tri->triangles = std::make_unique<fbs::GeometryTrianglesNV>(0xb1, 16, 100, 106, 12, 0xb2, 32,
                                                                300, 1, 0xb3, 48);
    tri->aabbs = std::make_unique<fbs::GeometryAabbNV>(0, 0, 24, 0);
    auto box = std::make_unique<fbs::GeometryNVT>();
    box->geometry_type = 1;
    box->flags = 2;
    box->triangles = std::make_unique<fbs::GeometryTrianglesNV>();
    box->aabbs = std::make_unique<fbs::GeometryAabbNV>(0xb4, 10, 32, 64);
    info->geometries.push_back(std::move(tri));
    info->geometries.push_back(std::move(box));
    return info;
}

// A copy, a fill and an update of buffers.
void append_transfers(std::vector<fbs::RecordT>& out, EveryKindBytes& bytes) {
    {
        fbs::CmdCopyBufferT r;
        r.command_buffer = 0xcb;
        r.version = 2;
        r.src_buffer = 0xb1;
        r.dst_buffer = 0xb2;
        r.regions = {fbs::BufferCopy(0, 16, 300), fbs::BufferCopy(400, 800, 77)};
        r.inputs = {bytes.snap(0x8000, bytes.a), bytes.snap(0x8190, bytes.b)};
        r.outputs = {bytes.snap(0x9010, bytes.a)};  // same bytes as an input: stored once
        out.push_back(record(std::move(r)));
    }
    {
        fbs::CmdFillBufferT r;
        r.command_buffer = 0xcb;
        r.dst_buffer = 0xb2;
        r.dst_offset = 4;
        r.size = ~uint64_t{0};
        r.data = 0xdeadbeef;
        out.push_back(record(r));
    }
    {
        fbs::CmdUpdateBufferT r;
        r.command_buffer = 0xcb;
        r.dst_buffer = 0xb2;
        r.dst_offset = 8;
        r.data = {1, 2, 3, 4, 5, 6, 7, 8};
        out.push_back(record(r));
    }
}

// An indirect dispatch with a storage buffer and push constants.
void append_dispatch(std::vector<fbs::RecordT>& out, EveryKindBytes& bytes) {
    {
        fbs::CmdDispatchT r;
        r.command_buffer = 0xcb;
        r.pipeline = 0x91;
        r.group_count_x = 64;
        r.group_count_y = 2;
        r.group_count_z = 1;
        r.indirect_buffer = 0xb3;
        r.indirect_offset = 12;
        r.base_group_x = 1;
        r.base_group_y = 2;
        r.base_group_z = 3;
        r.storage_buffers = {fbs::BoundBufferRange(0, 1, 2, 7, 0xb1, 0, 300, 0x8000)};
        r.push_constants = {9, 9, 9, 9};
        r.inputs = {bytes.snap(0x8000, bytes.a)};
        r.outputs = {bytes.snap(0x8190, bytes.b)};
        out.push_back(record(std::move(r)));
    }
}

// The three captured build commands (cluster, NV, NV deserialization) and a cluster size query.
void append_builds(std::vector<fbs::RecordT>& out, EveryKindBytes& bytes) {
    {
        fbs::CmdBuildClusterAccelerationStructureIndirectT r;
        r.command_buffer = 0xcb;
        r.input = cluster_input(0);
        r.dst_implicit_data = 0xa000;
        r.scratch_data = 0xb000;
        r.dst_addresses_array = std::make_unique<fbs::StridedDeviceAddressRegion>(0xc000, 8, 64);
        r.dst_sizes_array = std::make_unique<fbs::StridedDeviceAddressRegion>(0xd000, 4, 32);
        r.src_infos_array = std::make_unique<fbs::StridedDeviceAddressRegion>(0xe000, 64, 512);
        r.src_infos_count = 0xf000;
        r.address_resolution_flags = 0x3f;
        r.unrecorded_next_stypes = {7};
        r.inputs = {bytes.snap(0xe000, bytes.a), bytes.snap(0xf000, bytes.b)};
        r.outputs = {bytes.snap(0xc000, bytes.b)};
        r.driver_bvh = {fbs::DeviceAddressRange(0xc100, 0x2a00)};  // a traceable BLAS's BVH
        out.push_back(record(std::move(r)));
    }
    {
        fbs::CmdBuildAccelerationStructureNVT r;
        r.command_buffer = 0xcb;
        r.info = nv_bottom_level_info();
        r.instance_data = 0;
        r.instance_offset = 0;
        r.update = true;
        r.dst = 0xa6;
        r.src = 0xa5;
        r.scratch = 0xb5;
        r.scratch_offset = 256;
        r.inputs = {bytes.snap(0x8000, bytes.a)};
        out.push_back(record(std::move(r)));
    }
    {
        fbs::CmdCopyMemoryToAccelerationStructureT r;
        r.command_buffer = 0xcb;
        r.src_address = 0x10000;
        r.dst = 0xa6;
        r.mode = 3;
        r.inputs = {bytes.snap(0x10000, bytes.b)};
        out.push_back(record(std::move(r)));
    }
    {
        fbs::GetClusterBuildSizesT r;
        r.input = cluster_input(1);
        r.acceleration_structure_size = 1 << 20;
        r.update_scratch_size = 5;
        r.build_scratch_size = 1 << 16;
        out.push_back(record(std::move(r)));
    }
}

// Transfers, a dispatch and the three captured build commands.
void append_transfer_and_build_records(std::vector<fbs::RecordT>& out, EveryKindBytes& bytes) {
    append_transfers(out, bytes);
    append_dispatch(out, bytes);
    append_builds(out, bytes);
}

// Submissions and the host's waits.
void append_queue_and_host_sync_records(std::vector<fbs::RecordT>& out, EveryKindBytes& bytes) {
    TraceWriter& w = bytes.writer;
    {
        fbs::QueueSubmitT r;
        r.queue = 0x51;
        r.queue_family_index = 1;
        r.queue_index = 2;
        r.version = 2;
        r.fence = 0xf1;
        auto batch = std::make_unique<fbs::SubmitBatchT>();
        batch->wait_semaphores = {fbs::SemaphoreOp(0x5e1, 10, 0x02000000, 0)};
        batch->command_buffers = {0xcb, 0xcc};
        batch->signal_semaphores = {fbs::SemaphoreOp(0x5e2, 11, 0x1000, 1)};
        batch->flags = 1;
        r.batches.push_back(std::move(batch));
        r.submission_index = w.next_submission_index();
        r.result = 0;
        out.push_back(record(std::move(r)));
    }
    {
        fbs::QueueWaitIdleT r;
        r.queue = 0x51;
        r.result = -4;
        out.push_back(record(r));
    }
    {
        fbs::DeviceWaitIdleT r;
        r.result = -4;
        out.push_back(record(r));
    }
    {
        fbs::FenceWaitT r;
        r.fences = {0xf1, 0xf2};
        r.wait_all = true;
        r.timeout = 1000;
        r.result = 2;
        out.push_back(record(r));
    }
    {
        fbs::FenceResetT r;
        r.fences = {0xf1};
        out.push_back(record(r));
    }
    {
        fbs::FenceStatusT r;
        r.fence = 0xf1;
        r.result = 1;
        out.push_back(record(r));
    }
    {
        fbs::HostSemaphoreOpT r;
        r.op = 1;
        r.semaphores = {0x5e1};
        r.values = {12};
        r.wait_any = true;
        r.timeout = 5;
        r.result = 2;
        out.push_back(record(r));
    }
}

// Timestamps, labels, a ray check and a capture finding.
void append_timing_and_check_records(std::vector<fbs::RecordT>& out) {
    {
        fbs::GpuTimestampT r;
        r.command_buffer = 0xcb;
        r.query_pool = 0x9;
        r.query = 3;
        r.stage_mask = 0x2000;
        r.ticks = 123456789;
        r.ticks_valid = true;
        out.push_back(record(r));
    }
    {
        fbs::CpuTimestampT r;
        r.clock = 1;
        r.nanoseconds = 987654321;
        r.label = "submit";
        out.push_back(record(r));
    }
    {
        fbs::CalibratedTimestampsT r;
        r.gpu_ticks = 1;
        r.cpu_nanoseconds = 2;
        r.max_deviation_ns = 3;
        out.push_back(record(r));
    }
    {
        fbs::DebugLabelT r;
        r.command_buffer = 0xcb;
        r.queue = 0;
        r.op = 0;
        r.text = "build clusters";
        out.push_back(record(r));
    }
    {
        fbs::RayQueryCheckT r;
        r.acceleration_structure = 0xa5;
        r.device_handle = 0x7000100;
        r.after_submission = 4;
        r.label = "fixed rays";
        r.rays.push_back(fbs::TracedRay(0.f, 1.f, -5.f, 0.001f, 0.f, 0.f, 1.f, 1e30f, 1u, 0xffu));
        r.results.push_back(fbs::RayHitResult(1u, 5.25f, 7u, 2u, 31u, 0u, 0xfeu, 0.25f, 0.5f));
        out.push_back(record(r));
    }
    {
        fbs::CaptureFindingT r;
        r.command_buffer = 0xcb;
        r.command_index = 3;
        r.submission = 2;
        r.op_index = 17;
        r.severity = 2;
        r.rule = "VUID-VkClusterAccelerationStructureBuildTriangleClusterInfoNV-clusterID-10487";
        r.message = "clusterID is 0xFFFFFFFF";
        out.push_back(record(r));
    }
}

// Presentation, frames, secondaries, sparse binds and a draw.
void append_present_and_frame_records(std::vector<fbs::RecordT>& out) {
    {
        fbs::QueuePresentT r;
        r.queue = 0x9e;
        r.frame = 41;
        r.wait_semaphores = {0x5e2, 0x5e3};
        r.swapchains = {0x5c};
        r.image_indices = {2};
        r.result = 1000001003;  // VK_SUBOPTIMAL_KHR
        out.push_back(record(r));
    }
    {
        fbs::FrameBoundaryT r;
        r.queue = 0x9e;
        r.carrier = 1;  // vkQueueSubmit2
        r.submission = 12;
        r.batch = 1;
        r.flags = 1;  // VK_FRAME_BOUNDARY_FRAME_END_BIT_EXT
        r.frame_id = 0x1234567890ull;
        r.frame = 6;
        r.images = {0x1a};
        r.buffers = {0xb1, 0xb2};
        r.tag_name = 0x7a6;
        r.tag = {0, 0xff, 0x10};
        out.push_back(record(r));
    }
    {
        fbs::PreRangeStateT r;  // format 1.5
        r.queue = 0x9e;
        r.before_frame = 2;
        r.prelude_submission = 0;
        r.structures = 6;
        r.commands = 4;
        r.input_bytes = 0x1c4a0;
        r.cluster_commands = 1;
        out.push_back(record(r));
    }
    {
        fbs::CmdExecuteCommandsT r;
        r.command_buffer = 0xcb;
        r.secondaries = {0x5c1, 0x5c2, 0x5c1};
        out.push_back(record(r));
    }
    {
        fbs::AcquireNextImageT r;
        r.swapchain = 0x5c;
        r.timeout = ~0ull;
        r.semaphore = 0x5e4;
        r.fence = 0xf3;
        r.image_index = 2;
        r.result = 1000001003;  // VK_SUBOPTIMAL_KHR
        r.device_mask = 1;
        out.push_back(record(r));
    }
    {
        // Two batches: binary waits and two buffers' binds (an unbind, a bind at a memory
        // offset, one with a flag), counted image binds; then timeline signals and the fence.
        fbs::QueueBindSparseT r;
        r.queue = 0x9a;
        auto first = std::make_unique<fbs::SparseBindBatchT>();
        first->wait_semaphores = {fbs::SemaphoreOp(0x5e1, 0, 0, 0)};
        auto sparse = std::make_unique<fbs::SparseBufferBindT>();
        sparse->buffer = 0xd01;
        sparse->device_address = 0x50000000;
        sparse->binds = {fbs::SparseMemoryBind(0, 0x10000, 0x10, 0x20000, 0),
                         fbs::SparseMemoryBind(0x10000, 0x10000, 0, 0, 0),
                         fbs::SparseMemoryBind(0x20000, 0x10000, 0x11, 0, 1)};
        first->buffer_binds.push_back(std::move(sparse));
        auto other = std::make_unique<fbs::SparseBufferBindT>();
        other->buffer = 0xd02;
        other->binds = {fbs::SparseMemoryBind(0x4000, 0x1000, 0x10, 0x8000, 0)};
        first->buffer_binds.push_back(std::move(other));
        first->image_opaque_bind_count = 2;
        first->image_bind_count = 1;
        r.batches.push_back(std::move(first));
        auto second = std::make_unique<fbs::SparseBindBatchT>();
        second->signal_semaphores = {fbs::SemaphoreOp(0x5e2, 7, 0, 0)};
        r.batches.push_back(std::move(second));
        r.fence = 0xf4;
        r.result = 0;
        out.push_back(record(r));
    }
    {
        // A mesh-shader draw whose task and mesh stages write through device addresses.
        fbs::CmdDrawT r;
        r.command_buffer = 0xcb1;
        r.pipeline = 0x91;
        r.entry_point = "vkCmdDrawMeshTasksEXT";
        r.address_stages = 0x80000ull | 0x100000ull;  // TASK_SHADER_EXT | MESH_SHADER_EXT
        out.push_back(record(r));
    }
}

}  // namespace

std::vector<fbs::RecordT> one_of_every_kind(TraceWriter& w) {
    std::vector<fbs::RecordT> out;
    EveryKindBytes bytes(w);
    append_memory_and_object_records(out, bytes);
    append_command_buffer_and_sync_records(out);
    append_transfer_and_build_records(out, bytes);
    append_queue_and_host_sync_records(out, bytes);
    append_timing_and_check_records(out);
    append_present_and_frame_records(out);
    auto snap = [&](uint64_t address, const std::vector<uint8_t>& v) {
        return bytes.snap(address, v);
    };
    const std::vector<uint8_t>& a = bytes.a;
    const std::vector<uint8_t>& b = bytes.b;
    append_acceleration_structure_use_records(out);
    // The reader checks the snapshots of these records (traces::record_snapshots): contents
    // stored here.
    for (fbs::RecordT& r : out) {
        if (auto* build = r.body.AsCmdBuildAccelerationStructuresKHR()) {
            build->inputs = {snap(0xb000, a)};
            build->outputs = {snap(0xa100, b)};
        } else if (auto* rays = r.body.AsCmdTraceRays()) {
            rays->inputs = {snap(0xe000, b)};
        } else if (auto* writes = r.body.AsDeviceAddressWrites()) {
            writes->writes = {snap(0xb040, a)};
        }
    }
    return out;
}


std::vector<uint64_t> append_build_snapshotting(
    TraceWriter& writer, const std::vector<SnapshotPiece>& pieces,
    std::map<uint64_t, std::vector<uint8_t>>& bytes_by_key) {
    std::vector<uint64_t> keys;
    fbs::CmdBuildClusterAccelerationStructureIndirectT build;
    build.command_buffer = 0xcb;
    for (const SnapshotPiece& p : pieces) {
        fbs::MemorySnapshot s;
        EXPECT_FALSE(writer.snapshot(p.buffer, 0, 0x1000 * p.buffer, p.bytes, p.size, &s));
        const auto* b = static_cast<const uint8_t*>(p.bytes);
        bytes_by_key[s.hash()].assign(b, b + p.size);
        keys.push_back(s.hash());
        build.inputs.push_back(s);
    }
    fbs::RecordT r;
    r.body.Set(std::move(build));
    EXPECT_FALSE(writer.append(r));
    return keys;
}

std::string temp_path(const std::string& name) {
    auto dir = std::filesystem::temp_directory_path() / "clastrace-trace-tests";
    std::filesystem::create_directories(dir);
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    std::string prefix =
        info ? std::string(info->test_suite_name()) + "." + info->name() + "." : "";
    return (dir / (prefix + name)).string();
}

std::vector<uint8_t> read_file(const std::string& path) {
    std::ifstream in(path, std::ios::binary);
    return std::vector<uint8_t>(std::istreambuf_iterator<char>(in),
                                std::istreambuf_iterator<char>());
}

void write_file(const std::string& path, const std::vector<uint8_t>& bytes) {
    std::ofstream out(path, std::ios::binary | std::ios::trunc);
    out.write(reinterpret_cast<const char*>(bytes.data()),
              static_cast<std::streamsize>(bytes.size()));
}

ReadResult drain(std::unique_ptr<TraceReader> reader, const TraceError& error) {
    ReadResult r;
    if (!reader) {
        r.open_error = error;
        return r;
    }
    r.opened = true;
    r.has_index = reader->has_index();
    RecordView v;
    while (reader->next(&v)) {
        fbs::RecordT t;
        v.record->UnPackTo(&t);
        r.records.push_back(std::move(t));
    }
    r.damage = reader->damage();
    r.damage_count = reader->damage_count();
    r.stats = reader->stats();
    return r;
}

ReadResult read_all(const std::string& path) { return read_all(path, kVerifyEverything); }

ReadResult read_all(const std::string& path, const TraceReaderOptions& options) {
    TraceError e;
    auto reader = TraceReader::open(path, &e, options);
    return drain(std::move(reader), e);
}

ReadResult read_all_memory(const std::vector<uint8_t>& bytes) {
    return read_all_memory(bytes, kVerifyEverything);
}

ReadResult read_all_memory(const std::vector<uint8_t>& bytes, const TraceReaderOptions& options) {
    TraceError e;
    auto reader = TraceReader::open_memory(bytes.data(), bytes.size(), "memory.clt", &e, options);
    return drain(std::move(reader), e);
}

std::vector<fbs::RecordT> write_frames_trace(const std::string& path, int submissions,
                                             uint32_t chunk_bytes, TraceWriterOptions options) {
    options.chunk_raw_bytes = chunk_bytes;
    TraceError e;
    auto w = TraceWriter::create(path, test_header(), options, &e);
    EXPECT_TRUE(w) << e.message;
    std::vector<fbs::RecordT> out;
    if (!w) return out;
    std::mt19937 rng(7);
    std::vector<float> vertices(3 * 256);
    std::vector<uint8_t> indices(3 * 256);
    for (int s = 0; s < submissions; ++s) {
        // Every third frame reuses the previous geometry: realistic repetition to dedup.
        if (s % 3 != 2) {
            for (size_t i = 0; i < vertices.size(); ++i)
                vertices[i] = std::sin(0.01f * static_cast<float>(i + 1000 * s));
            for (size_t i = 0; i < indices.size(); ++i)
                indices[i] = static_cast<uint8_t>(rng() % 256);
        }
        fbs::CommandBufferBeginT begin;
        begin.command_buffer = 0xcb;
        fbs::RecordT r;
        r.body.Set(begin);
        EXPECT_FALSE(w->append(r));
        out.push_back(std::move(r));

        fbs::CmdBuildClusterAccelerationStructureIndirectT build;
        build.command_buffer = 0xcb;
        build.input = std::make_unique<fbs::ClusterInputInfoT>();
        build.input->op_type = 2;
        build.input->max_acceleration_structure_count = static_cast<uint32_t>(s + 1);
        fbs::MemorySnapshot snap;
        EXPECT_FALSE(w->snapshot(1, 0, 0x1000, vertices.data(), vertices.size() * 4, &snap));
        build.inputs.push_back(snap);
        EXPECT_FALSE(w->snapshot(2, 0, 0x2000, indices.data(), indices.size(), &snap));
        build.inputs.push_back(snap);
        fbs::RecordT br;
        br.body.Set(std::move(build));
        EXPECT_FALSE(w->append(br));
        out.push_back(std::move(br));

        fbs::QueueSubmitT submit;
        submit.queue = 0x51;
        submit.submission_index = w->next_submission_index();
        fbs::RecordT sr;
        sr.body.Set(std::move(submit));
        EXPECT_FALSE(w->append(sr));
        out.push_back(std::move(sr));
    }
    EXPECT_FALSE(w->finish());
    return out;
}

std::string describe(const std::vector<TraceError>& damage) {
    std::string s;
    for (const TraceError& e : damage)
        s += "  [" + std::string(trace_error_code_name(e.code)) + "] " + e.message + "\n";
    return s;
}

}  // namespace clastrace::traces::testing
