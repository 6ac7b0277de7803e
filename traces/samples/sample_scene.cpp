// SPDX-License-Identifier: Apache-2.0
#include "sample_scene.h"

#include <clastrace/traces/trace_writer.h>
#include <clastrace/vk_cluster_abi.h>

#include <cmath>
#include <cstring>
#include <vector>

namespace clastrace::samples {

using namespace clastrace::traces;

namespace {

// Handles and device addresses as a driver might hand them out.
constexpr uint64_t kDeviceLocalMemory = 0x1001, kHostMemory = 0x1002;
constexpr uint64_t kVertexBuffer = 0x2001, kIndex8Buffer = 0x2002, kIndex32Buffer = 0x2003,
                   kStagingBuffer = 0x2004, kInfoBuffer = 0x2005, kClusterBuffer = 0x2006,
                   kDstAddressBuffer = 0x2007, kDstSizeBuffer = 0x2008, kScratchBuffer = 0x2009,
                   kBlasScratchBuffer = 0x200a;
constexpr uint64_t kBlas = 0x3001, kCommandBuffer = 0x4001, kQueue = 0x5001, kFence = 0x6001,
                   kQueryPool = 0x7001;
constexpr uint64_t kAddressBase = 0x00007f3a00000000ull;

constexpr uint32_t kGrid = 9;                                          // 9x9 vertices per cluster
constexpr uint32_t kClusterVertices = kGrid * kGrid;                   // 81
constexpr uint32_t kClusterTriangles = (kGrid - 1) * (kGrid - 1) * 2;  // 128
constexpr uint32_t kClusters = 2;

template <class T>
fbs::RecordT record(T body) {
    fbs::RecordT r;
    r.body.Set(std::move(body));
    return r;
}

struct SceneBuffer {
    uint64_t handle;
    uint64_t size;
    uint64_t usage;
    uint64_t memory;
    uint64_t memory_offset;
    uint64_t address;
};

fbs::TraceHeaderT sample_header() {
    fbs::TraceHeaderT h;
    h.device = std::make_unique<fbs::DeviceInfoT>();
    fbs::DeviceInfoT& d = *h.device;
    d.name = "NVIDIA GeForce RTX 4080 (sample)";
    d.vendor_id = 0x10de;
    d.device_id = 0x2704;
    d.driver_version = (565u << 22) | (57u << 14) | (1u << 6);  // NVIDIA packs 565.57.1 this way
    d.api_version = VK_MAKE_API_VERSION(0, 1, 4, 303);
    d.device_type = VK_PHYSICAL_DEVICE_TYPE_DISCRETE_GPU;
    d.driver_id = VK_DRIVER_ID_NVIDIA_PROPRIETARY;
    d.driver_name = "NVIDIA";
    d.driver_info = "565.57.01";
    d.pipeline_cache_uuid.assign(16, 0);
    for (int i = 0; i < 16; ++i) d.pipeline_cache_uuid[i] = static_cast<uint8_t>(0xa0 + i);
    d.timestamp_period_ns = 1.0f;
    d.memory_types = {fbs::MemoryType(VK_MEMORY_PROPERTY_DEVICE_LOCAL_BIT, 0),
                      fbs::MemoryType(VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT |
                                          VK_MEMORY_PROPERTY_HOST_COHERENT_BIT,
                                      1)};
    d.memory_heaps = {fbs::MemoryHeap(16ull << 30, VK_MEMORY_HEAP_DEVICE_LOCAL_BIT),
                      fbs::MemoryHeap(64ull << 30, 0)};
    d.enabled_extensions = {VK_NV_CLUSTER_ACCELERATION_STRUCTURE_EXTENSION_NAME,
                            "VK_KHR_acceleration_structure", "VK_NV_ray_tracing",
                            "VK_KHR_synchronization2", "VK_KHR_buffer_device_address"};
    d.cluster_features = std::make_unique<fbs::ClusterFeaturesT>();
    d.cluster_features->cluster_acceleration_structure_supported = true;
    d.cluster_features->cluster_acceleration_structure_enabled = true;
    d.cluster_properties = std::make_unique<fbs::ClusterPropertiesT>();
    fbs::ClusterPropertiesT& p = *d.cluster_properties;
    p.max_vertices_per_cluster = 256;
    p.max_triangles_per_cluster = 256;
    p.cluster_scratch_byte_alignment = 128;
    p.cluster_byte_alignment = 128;
    p.cluster_template_byte_alignment = 32;
    p.cluster_bottom_level_byte_alignment = 256;
    p.cluster_template_bounds_byte_alignment = 32;
    p.max_cluster_geometry_index = 16777215;
    d.ray_tracing_properties_nv = std::make_unique<fbs::RayTracingPropertiesNVT>();
    d.ray_tracing_properties_nv->shader_group_handle_size = 32;
    d.ray_tracing_properties_nv->max_recursion_depth = 31;
    d.ray_tracing_properties_nv->max_shader_group_stride = 4096;
    d.ray_tracing_properties_nv->shader_group_base_alignment = 64;
    d.ray_tracing_properties_nv->max_geometry_count = 16777215;
    d.ray_tracing_properties_nv->max_instance_count = 16777215;
    d.ray_tracing_properties_nv->max_triangle_count = 536870911;
    d.ray_tracing_properties_nv->max_descriptor_set_acceleration_structures = 1048576;
    h.capture = std::make_unique<fbs::CaptureSettingsT>();
    h.capture->application_name = "cluster-grid";
    h.capture->engine_name = "clastrace sample generator";
    h.capture->capture_tool = "clastrace-make-sample";
    h.capture->start_time_unix_ns =
        1'764'000'000'000'000'000ull;  // fixed: the sample is reproducible
    h.capture->snapshot_policy = "inputs+outputs";
    return h;
}

// Two 9x9 vertex grids (one per cluster), slightly curved so they are not flat.
std::vector<float> grid_vertices() {
    std::vector<float> v;
    for (uint32_t c = 0; c < kClusters; ++c) {
        for (uint32_t y = 0; y < kGrid; ++y) {
            for (uint32_t x = 0; x < kGrid; ++x) {
                float fx = static_cast<float>(x) / (kGrid - 1) + static_cast<float>(c);
                float fy = static_cast<float>(y) / (kGrid - 1);
                v.push_back(fx);
                v.push_back(fy);
                v.push_back(0.125f * std::sin(3.0f * fx) * std::cos(2.0f * fy));
            }
        }
    }
    return v;
}

// Triangle indices of one grid, local to its cluster (fits 8 bits: 81 vertices).
std::vector<uint32_t> grid_indices() {
    std::vector<uint32_t> idx;
    for (uint32_t y = 0; y + 1 < kGrid; ++y) {
        for (uint32_t x = 0; x + 1 < kGrid; ++x) {
            uint32_t a = y * kGrid + x, b = a + 1, c = a + kGrid, d = c + 1;
            idx.insert(idx.end(), {a, b, c, b, d, c});
        }
    }
    return idx;
}

using ClusterInfo = VkClusterAccelerationStructureBuildTriangleClusterInfoNV;

// The scene's contents and the buffers that hold them, as the commands below read them.
struct SampleScene {
    std::vector<float> vertices;
    std::vector<uint8_t> index8;
    std::vector<uint32_t> index32;
    std::vector<SceneBuffer> buffers;
    std::vector<ClusterInfo> infos;  // srcInfosArray contents

    uint64_t info_bytes() const { return infos.size() * sizeof(ClusterInfo); }
    uint64_t address_of(uint64_t handle) const {
        for (const SceneBuffer& b : buffers)
            if (b.handle == handle) return b.address;
        return uint64_t{0};
    }
};

// The buffers, placed in their memory; those with device addresses get them from kAddressBase.
std::vector<SceneBuffer> scene_buffers(const SampleScene& scene) {
    const uint64_t storage =
        VK_BUFFER_USAGE_SHADER_DEVICE_ADDRESS_BIT | VK_BUFFER_USAGE_STORAGE_BUFFER_BIT;
    const uint64_t build_input =
        storage | VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_BIT_KHR;
    const uint64_t as_storage = storage | VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_STORAGE_BIT_KHR;
    const uint64_t info_bytes = kClusters * sizeof(ClusterInfo);
    std::vector<SceneBuffer> buffers = {
        {kVertexBuffer, scene.vertices.size() * sizeof(float),
         build_input | VK_BUFFER_USAGE_RAY_TRACING_BIT_NV, kDeviceLocalMemory, 0, 0},
        {kIndex8Buffer, scene.index8.size(), build_input, kDeviceLocalMemory, 0x1000, 0},
        {kIndex32Buffer, scene.index32.size() * 4, build_input | VK_BUFFER_USAGE_RAY_TRACING_BIT_NV,
         kDeviceLocalMemory, 0x2000, 0},
        {kStagingBuffer, info_bytes, VK_BUFFER_USAGE_TRANSFER_SRC_BIT, kHostMemory, 0, 0},
        {kInfoBuffer, info_bytes, build_input | VK_BUFFER_USAGE_TRANSFER_DST_BIT,
         kDeviceLocalMemory, 0x3000, 0},
        {kClusterBuffer, 64 << 10, as_storage, kDeviceLocalMemory, 0x10000, 0},
        {kDstAddressBuffer, kClusters * 8, as_storage, kDeviceLocalMemory, 0x4000, 0},
        {kDstSizeBuffer, kClusters * 4, storage, kDeviceLocalMemory, 0x4100, 0},
        {kScratchBuffer, 32 << 10, storage, kDeviceLocalMemory, 0x20000, 0},
        {kBlasScratchBuffer, 32 << 10, VK_BUFFER_USAGE_RAY_TRACING_BIT_NV, kDeviceLocalMemory,
         0x30000, 0},
    };
    for (SceneBuffer& b : buffers) {
        b.address = (b.usage & VK_BUFFER_USAGE_SHADER_DEVICE_ADDRESS_BIT)
                        ? kAddressBase + (b.memory == kHostMemory ? 0x100000 : 0) + b.memory_offset
                        : 0;
    }
    return buffers;
}

// One VkClusterAccelerationStructureBuildTriangleClusterInfoNV per cluster.
std::vector<ClusterInfo> cluster_infos(const SampleScene& scene) {
    std::vector<ClusterInfo> infos(kClusters);
    for (uint32_t c = 0; c < kClusters; ++c) {
        ClusterInfo& i = infos[c];
        std::memset(&i, 0, sizeof i);
        i.clusterID = 100 + c;
        i.triangleCount = kClusterTriangles;
        i.vertexCount = kClusterVertices;
        i.positionTruncateBitCount = 0;
        i.indexType = VK_CLUSTER_ACCELERATION_STRUCTURE_INDEX_FORMAT_8BIT_NV;
        i.baseGeometryIndexAndGeometryFlags.geometryIndex = 0;
        i.baseGeometryIndexAndGeometryFlags.geometryFlags =
            VK_CLUSTER_ACCELERATION_STRUCTURE_GEOMETRY_OPAQUE_BIT_NV;
        i.indexBufferStride = 1;
        i.vertexBufferStride = 12;
        i.indexBuffer = scene.address_of(kIndex8Buffer) + c * kClusterTriangles * 3;
        i.vertexBuffer = scene.address_of(kVertexBuffer) + c * kClusterVertices * 12;
    }
    return infos;
}

SampleScene make_scene() {
    SampleScene scene;
    scene.vertices = grid_vertices();
    const std::vector<uint32_t> local = grid_indices();
    for (uint32_t c = 0; c < kClusters; ++c) {
        for (uint32_t i : local) {
            scene.index8.push_back(static_cast<uint8_t>(i));
            scene.index32.push_back(i + c * kClusterVertices);
        }
    }
    scene.buffers = scene_buffers(scene);
    scene.infos = cluster_infos(scene);
    return scene;
}

#define TRY(expr)                              \
    do {                                       \
        if (TraceError e_ = (expr)) return e_; \
    } while (0)

TraceError write_memory(TraceWriter& writer) {
    fbs::MemoryAllocateT device_memory;
    device_memory.memory = kDeviceLocalMemory;
    device_memory.size = 1 << 20;
    device_memory.memory_type_index = 0;
    device_memory.allocate_flags = VK_MEMORY_ALLOCATE_DEVICE_ADDRESS_BIT;
    TRY(writer.append(record(device_memory)));
    fbs::MemoryAllocateT host_memory;
    host_memory.memory = kHostMemory;
    host_memory.size = 64 << 10;
    host_memory.memory_type_index = 1;
    host_memory.allocate_flags = VK_MEMORY_ALLOCATE_DEVICE_ADDRESS_BIT;
    return writer.append(record(host_memory));
}

TraceError write_buffers(TraceWriter& writer, const std::vector<SceneBuffer>& buffers) {
    for (const SceneBuffer& b : buffers) {
        fbs::BufferCreateT create;
        create.buffer = b.handle;
        create.size = b.size;
        create.usage = b.usage;
        create.sharing_mode = VK_SHARING_MODE_EXCLUSIVE;
        TRY(writer.append(record(create)));
        fbs::BufferBindMemoryT bind;
        bind.buffer = b.handle;
        bind.memory = b.memory;
        bind.memory_offset = b.memory_offset;
        bind.device_address = b.address;
        TRY(writer.append(record(bind)));
    }
    return {};
}

// The NV bottom-level structure over the same triangles (the classic path, for comparison).
std::unique_ptr<fbs::AccelerationStructureInfoNVT> blas_info(const SampleScene& scene) {
    auto info = std::make_unique<fbs::AccelerationStructureInfoNVT>();
    info->type = VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_NV;
    info->flags = VK_BUILD_ACCELERATION_STRUCTURE_PREFER_FAST_TRACE_BIT_NV;
    auto geometry = std::make_unique<fbs::GeometryNVT>();
    geometry->geometry_type = VK_GEOMETRY_TYPE_TRIANGLES_NV;
    geometry->flags = VK_GEOMETRY_OPAQUE_BIT_NV;
    geometry->triangles =
        std::make_unique<fbs::GeometryTrianglesNV>(kVertexBuffer, 0, kClusters * kClusterVertices,
                                                   VK_FORMAT_R32G32B32_SFLOAT, 12, kIndex32Buffer,
                                                   0, static_cast<uint32_t>(scene.index32.size()),
                                                   VK_INDEX_TYPE_UINT32, 0, 0);
    geometry->aabbs = std::make_unique<fbs::GeometryAabbNV>(0, 0, 24, 0);
    info->geometries.push_back(std::move(geometry));
    return info;
}

// The bottom-level structure's creation, its memory requirements and its binding.
TraceError write_blas_object(TraceWriter& writer, const SampleScene& scene) {
    fbs::AccelerationStructureCreateT blas;
    blas.acceleration_structure = kBlas;
    blas.api = 0;
    blas.type = VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_NV;
    blas.info = blas_info(scene);
    blas.device_address = 0x00000000deadb000ull;
    TRY(writer.append(record(std::move(blas))));
    fbs::AccelerationStructureMemoryRequirementsNVT req;
    req.acceleration_structure = kBlas;
    req.type = VK_ACCELERATION_STRUCTURE_MEMORY_REQUIREMENTS_TYPE_OBJECT_NV;
    req.size = 24576;
    req.alignment = 256;
    req.memory_type_bits = 0x1;
    TRY(writer.append(record(req)));
    fbs::AccelerationStructureBindMemoryT blas_bind;
    blas_bind.acceleration_structure = kBlas;
    blas_bind.memory = kDeviceLocalMemory;
    blas_bind.memory_offset = 0x40000;
    return writer.append(record(blas_bind));
}

// The cluster build's inputs.
std::unique_ptr<fbs::ClusterInputInfoT> triangle_input() {
    auto in = std::make_unique<fbs::ClusterInputInfoT>();
    in->max_acceleration_structure_count = kClusters;
    in->flags = VK_BUILD_ACCELERATION_STRUCTURE_PREFER_FAST_TRACE_BIT_KHR;
    in->op_type = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV;
    in->op_mode = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV;
    fbs::TriangleClusterInputT t;
    t.vertex_format = VK_FORMAT_R32G32B32_SFLOAT;
    t.max_geometry_index_value = 0;
    t.max_cluster_unique_geometry_count = 1;
    t.max_cluster_triangle_count = kClusterTriangles;
    t.max_cluster_vertex_count = kClusterVertices;
    t.max_total_triangle_count = kClusters * kClusterTriangles;
    t.max_total_vertex_count = kClusters * kClusterVertices;
    t.min_position_truncate_bit_count = 0;
    in->op_input.Set(std::move(t));
    return in;
}

// The sizes the driver answered for the cluster build's inputs.
TraceError write_cluster_build_sizes(TraceWriter& writer) {
    fbs::GetClusterBuildSizesT sizes;
    sizes.input = triangle_input();
    sizes.acceleration_structure_size = 2 * 8192;
    sizes.update_scratch_size = 0;
    sizes.build_scratch_size = 12288;
    return writer.append(record(std::move(sizes)));
}

fbs::CpuTimestampT cpu_timestamp(uint64_t nanoseconds, const char* label) {
    fbs::CpuTimestampT t;
    t.clock = 0;
    t.nanoseconds = nanoseconds;
    t.label = label;
    return t;
}

fbs::GpuTimestampT gpu_timestamp(uint32_t query, uint64_t stage_mask, uint64_t ticks) {
    fbs::GpuTimestampT t;
    t.command_buffer = kCommandBuffer;
    t.query_pool = kQueryPool;
    t.query = query;
    t.stage_mask = stage_mask;
    t.ticks = ticks;
    t.ticks_valid = true;
    return t;
}

// Staging -> device copy of the infos: input and output hold the same bytes (stored once).
TraceError write_info_copy(TraceWriter& writer, const SampleScene& scene) {
    fbs::CmdCopyBufferT copy;
    copy.command_buffer = kCommandBuffer;
    copy.version = 1;
    copy.src_buffer = kStagingBuffer;
    copy.dst_buffer = kInfoBuffer;
    copy.regions.emplace_back(0, 0, scene.info_bytes());
    fbs::MemorySnapshot snap;
    TRY(writer.snapshot(kStagingBuffer, 0, scene.address_of(kStagingBuffer), scene.infos.data(),
                        scene.info_bytes(), &snap));
    copy.inputs.push_back(snap);
    TRY(writer.snapshot(kInfoBuffer, 0, scene.address_of(kInfoBuffer), scene.infos.data(),
                        scene.info_bytes(), &snap));
    copy.outputs.push_back(snap);
    TRY(writer.append(record(std::move(copy))));

    fbs::CmdPipelineBarrierT barrier;
    barrier.command_buffer = kCommandBuffer;
    barrier.version = 2;
    barrier.dependency = std::make_unique<fbs::DependencyT>();
    barrier.dependency->buffer_barriers.emplace_back(
        VK_PIPELINE_STAGE_2_COPY_BIT, VK_ACCESS_2_TRANSFER_WRITE_BIT,
        VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
        VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT, VK_QUEUE_FAMILY_IGNORED, VK_QUEUE_FAMILY_IGNORED,
        kInfoBuffer, 0, VK_WHOLE_SIZE);
    return writer.append(record(std::move(barrier)));
}

// The cluster build: two triangle clusters into implicit destinations, with what it read and wrote.
TraceError write_cluster_build(TraceWriter& writer, const SampleScene& scene) {
    fbs::CmdBuildClusterAccelerationStructureIndirectT build;
    build.command_buffer = kCommandBuffer;
    build.input = triangle_input();
    build.dst_implicit_data = scene.address_of(kClusterBuffer);
    build.scratch_data = scene.address_of(kScratchBuffer);
    build.dst_addresses_array =
        std::make_unique<fbs::StridedDeviceAddressRegion>(scene.address_of(kDstAddressBuffer), 8,
                                                          kClusters * 8);
    build.dst_sizes_array =
        std::make_unique<fbs::StridedDeviceAddressRegion>(scene.address_of(kDstSizeBuffer), 4,
                                                          kClusters * 4);
    build.src_infos_array =
        std::make_unique<fbs::StridedDeviceAddressRegion>(scene.address_of(kInfoBuffer),
                                                          sizeof(ClusterInfo), scene.info_bytes());
    build.src_infos_count = 0;
    build.address_resolution_flags = VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_NONE_NV;
    const uint64_t dst_addresses[kClusters] = {scene.address_of(kClusterBuffer),
                                               scene.address_of(kClusterBuffer) + 8192};
    const uint32_t dst_sizes[kClusters] = {7936, 7936};
    struct Piece {
        uint64_t buffer;
        const void* bytes;
        size_t size;
    };
    const Piece inputs[] = {{kInfoBuffer, scene.infos.data(), scene.info_bytes()},
                            {kIndex8Buffer, scene.index8.data(), scene.index8.size()},
                            {kVertexBuffer, scene.vertices.data(), scene.vertices.size() * 4}};
    const Piece outputs[] = {{kDstAddressBuffer, dst_addresses, sizeof dst_addresses},
                             {kDstSizeBuffer, dst_sizes, sizeof dst_sizes}};
    fbs::MemorySnapshot snap;
    for (const Piece& p : inputs) {
        TRY(writer.snapshot(p.buffer, 0, scene.address_of(p.buffer), p.bytes, p.size, &snap));
        build.inputs.push_back(snap);
    }
    for (const Piece& p : outputs) {
        TRY(writer.snapshot(p.buffer, 0, scene.address_of(p.buffer), p.bytes, p.size, &snap));
        build.outputs.push_back(snap);
    }
    TRY(writer.append(record(std::move(build))));

    fbs::CmdPipelineBarrierT as_barrier;
    as_barrier.command_buffer = kCommandBuffer;
    as_barrier.version = 2;
    as_barrier.dependency = std::make_unique<fbs::DependencyT>();
    as_barrier.dependency->memory_barriers.emplace_back(
        VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
        VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR,
        VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
        VK_ACCESS_2_ACCELERATION_STRUCTURE_READ_BIT_KHR);
    return writer.append(record(std::move(as_barrier)));
}

TraceError write_blas_build(TraceWriter& writer, const SampleScene& scene) {
    fbs::CmdBuildAccelerationStructureNVT nv_build;
    nv_build.command_buffer = kCommandBuffer;
    nv_build.info = blas_info(scene);
    nv_build.update = false;
    nv_build.dst = kBlas;
    nv_build.scratch = kBlasScratchBuffer;
    nv_build.scratch_offset = 0;
    fbs::MemorySnapshot snap;
    TRY(writer.snapshot(kVertexBuffer, 0, scene.address_of(kVertexBuffer), scene.vertices.data(),
                        scene.vertices.size() * 4, &snap));
    nv_build.inputs.push_back(snap);
    TRY(writer.snapshot(kIndex32Buffer, 0, scene.address_of(kIndex32Buffer), scene.index32.data(),
                        scene.index32.size() * 4, &snap));
    nv_build.inputs.push_back(snap);
    return writer.append(record(std::move(nv_build)));
}

// The frame's one command buffer: the infos' upload, the cluster build, the classic build,
// between two GPU timestamps.
TraceError write_command_buffer(TraceWriter& writer, const SampleScene& scene) {
    fbs::CommandBufferBeginT begin;
    begin.command_buffer = kCommandBuffer;
    begin.flags = VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT;
    TRY(writer.append(record(begin)));
    TRY(writer.append(
        record(gpu_timestamp(0, VK_PIPELINE_STAGE_2_TOP_OF_PIPE_BIT, 900'000'000ull))));
    TRY(write_info_copy(writer, scene));
    TRY(write_cluster_build(writer, scene));
    TRY(write_blas_build(writer, scene));
    TRY(writer.append(
        record(gpu_timestamp(1, VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                             900'000'000ull + 48'250))));
    fbs::CommandBufferEndT end;
    end.command_buffer = kCommandBuffer;
    return writer.append(record(end));
}

// The command buffer's submission, the wait for its fence, and a calibration after it.
TraceError write_submission(TraceWriter& writer) {
    fbs::QueueSubmitT submit;
    submit.queue = kQueue;
    submit.version = 2;
    auto batch = std::make_unique<fbs::SubmitBatchT>();
    batch->command_buffers.push_back(kCommandBuffer);
    submit.batches.push_back(std::move(batch));
    submit.fence = kFence;
    submit.submission_index = writer.next_submission_index();
    submit.result = VK_SUCCESS;
    TRY(writer.append(record(std::move(submit))));

    fbs::FenceWaitT wait;
    wait.fences.push_back(kFence);
    wait.wait_all = true;
    wait.timeout = UINT64_MAX;
    wait.result = VK_SUCCESS;
    TRY(writer.append(record(std::move(wait))));

    fbs::CalibratedTimestampsT calibrated;
    calibrated.gpu_ticks = 900'100'000ull;
    calibrated.cpu_nanoseconds = 5'000'150'000ull;
    calibrated.max_deviation_ns = 1200;
    return writer.append(record(calibrated));
}

}  // namespace

TraceError write_sample_trace(const std::string& path) {
    TraceError error;
    TraceWriterOptions options;
    options.chunk_raw_bytes = 8192;  // small chunks so the sample shows several of them
    options.zstd_level = 19;
    auto writer = TraceWriter::create(path, sample_header(), options, &error);
    if (!writer) return error;
    const SampleScene scene = make_scene();
    TRY(write_memory(*writer));
    TRY(write_buffers(*writer, scene.buffers));
    TRY(write_blas_object(*writer, scene));
    TRY(write_cluster_build_sizes(*writer));
    TRY(writer->append(record(cpu_timestamp(5'000'000'000ull, "frame 0 begin"))));
    TRY(write_command_buffer(*writer, scene));
    TRY(write_submission(*writer));
    TRY(writer->append(record(cpu_timestamp(5'000'200'000ull, "frame 0 end"))));
    return writer->finish();
}
#undef TRY

}  // namespace clastrace::samples
