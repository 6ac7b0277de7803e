#include "analyze_scene.h"

#include <clastrace/engine/execute.h>
#include <clastrace/engine/memory_image.h>
#include <clastrace/engine/object_directory.h>

#include <algorithm>
#include <cstring>
#include <stdexcept>

namespace clastrace::test {

namespace {
constexpr uint64_t kQueue = 0x9001, kFence = 0xfe1, kMemory = 0x1001;

template <class T>
fbs::RecordT record(T body) {
    fbs::RecordT r;
    r.body.Set(std::move(body));
    return r;
}
void check(const traces::TraceError& e) {
    if (e) throw std::runtime_error(e.message);
}
std::vector<uint8_t> bytes_of(const void* p, size_t n) {
    const auto* b = static_cast<const uint8_t*>(p);
    return {b, b + n};
}
}  // namespace

struct AnalyzeSceneWriter::Mirror {
    engine::MemoryImage image;
    engine::ObjectDirectory directory;
};

AnalyzeSceneWriter::~AnalyzeSceneWriter() = default;

void AnalyzeSceneWriter::add_buffer(uint64_t handle, uint64_t address, uint64_t size, uint64_t usage) {
    fbs::BufferCreateT c;
    c.buffer = handle;
    c.size = size;
    c.usage = usage;
    check(writer_->append(record(c)));
    fbs::BufferBindMemoryT b;
    b.buffer = handle;
    b.memory = kMemory;
    b.memory_offset = address - 0x10000000;
    b.device_address = address;
    check(writer_->append(record(b)));
    mirror_->image.add_region(address, size, static_cast<VkBufferUsageFlags>(usage), "mirror");
}

AnalyzeSceneWriter::AnalyzeSceneWriter(const std::string& path, float timestamp_period_ns)
    : mirror_(std::make_unique<Mirror>()) {
    fbs::TraceHeaderT h;
    h.device = std::make_unique<fbs::DeviceInfoT>();
    h.device->name = "test driver";
    h.device->driver_name = "NVIDIA";  // a driver trace: captured sizes may differ from the engine's
    h.device->timestamp_period_ns = timestamp_period_ns;
    h.capture = std::make_unique<fbs::CaptureSettingsT>();
    h.capture->capture_tool = "analyze_cli_tests";
    traces::TraceError e;
    traces::TraceWriterOptions o;
    o.sync_on_finish = false;
    writer_ = traces::TraceWriter::create(path, h, o, &e);
    check(e);
    const uint64_t sda = VK_BUFFER_USAGE_SHADER_DEVICE_ADDRESS_BIT;
    const uint64_t input = sda | VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_BIT_KHR;
    const uint64_t storage = sda | VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_STORAGE_BIT_KHR | VK_BUFFER_USAGE_STORAGE_BUFFER_BIT;
    using S = AnalyzeScene;
    add_buffer(S::kVertexBuffer, S::kVertices, 0x10000, input);
    add_buffer(S::kIndexBuffer, S::kIndices, 0x10000, input);
    add_buffer(0x2003, S::kInfos, 0x4000, input);
    add_buffer(0x2004, S::kArrays, 0x4000, storage | VK_BUFFER_USAGE_TRANSFER_SRC_BIT | VK_BUFFER_USAGE_TRANSFER_DST_BIT);
    add_buffer(S::kPoolBuffer, S::kPool, S::kPoolSize, storage | VK_BUFFER_USAGE_TRANSFER_SRC_BIT | VK_BUFFER_USAGE_TRANSFER_DST_BIT |
                                                      VK_BUFFER_USAGE_RAY_TRACING_BIT_NV);  // also the NV build's scratch
    add_buffer(0x2007, S::kSerialized, 0x1000, input);
    add_buffer(S::kAsBuffer, S::kAsStorage, 0x10000, storage);
    begin();
}

void AnalyzeSceneWriter::begin() {
    fbs::CommandBufferBeginT begin;
    begin.command_buffer = command_buffer_;
    begin.flags = VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT;
    check(writer_->append(record(begin)));
}

BuiltClusters AnalyzeSceneWriter::build(const ClusterBuild& call) {
    using S = AnalyzeScene;
    const auto n = static_cast<uint32_t>(call.triangle_counts.size());
    std::vector<VkClusterAccelerationStructureBuildTriangleClusterInfoNV> infos(n);
    std::vector<float> vertices;
    std::vector<uint32_t> indices;
    BuiltClusters built;
    uint32_t max_tris = 0, max_verts = 0;
    for (uint32_t c = 0; c < n; ++c) {
        const uint32_t t = call.triangle_counts[c], v = t + 2;
        auto& info = infos[c];
        std::memset(&info, 0, sizeof info);
        info.clusterID = 10 + c;
        info.triangleCount = t;
        info.vertexCount = v;
        info.positionTruncateBitCount = call.truncate_bits;
        info.indexType = VK_CLUSTER_ACCELERATION_STRUCTURE_INDEX_FORMAT_32BIT_NV;
        info.indexBufferStride = 4;
        info.vertexBufferStride = 12;
        info.indexBuffer = S::kIndices + indices.size() * 4;
        info.vertexBuffer = S::kVertices + vertices.size() * 4;
        // A zig-zag strip with fractional coordinates, so truncating mantissa bits changes them.
        for (uint32_t i = 0; i < v; ++i) {
            vertices.push_back(1.37f * float(i) + 0.123f + 8.0f * float(c));
            vertices.push_back(float(i % 2) * 1.91f + 0.017f * float(i));
            vertices.push_back(0.311f * float(i * i % 7));
        }
        for (uint32_t i = 0; i < t; ++i)
            for (uint32_t k : {i, i + 1, i + 2}) indices.push_back(k);
        built.triangles += t;
        built.vertices += v;
        max_tris = std::max(max_tris, t);
        max_verts = std::max(max_verts, v);
    }
    VkClusterAccelerationStructureTriangleClusterInputNV tri{};
    tri.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_TRIANGLE_CLUSTER_INPUT_NV;
    tri.vertexFormat = VK_FORMAT_R32G32B32_SFLOAT;
    tri.maxClusterUniqueGeometryCount = 1;
    tri.maxClusterTriangleCount = max_tris;
    tri.maxClusterVertexCount = max_verts;
    tri.maxTotalTriangleCount = static_cast<uint32_t>(built.triangles);
    tri.maxTotalVertexCount = static_cast<uint32_t>(built.vertices);
    VkClusterAccelerationStructureCommandsInfoNV info{};
    info.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_COMMANDS_INFO_NV;
    info.input.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_INPUT_INFO_NV;
    info.input.maxAccelerationStructureCount = n;
    info.input.opType = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV;
    info.input.opMode = call.mode;
    info.input.opInput.pTriangleClusters = &tri;
    const bool implicit = call.mode == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV;
    const bool explicit_mode = call.mode == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_EXPLICIT_DESTINATIONS_NV;
    info.dstImplicitData = implicit ? call.dst : 0;
    info.scratchData = call.scratch;
    info.dstAddressesArray = {call.arrays, 8, n * 8ull};
    info.dstSizesArray = {call.arrays + 0x200, 4, n * 4ull};
    info.srcInfosArray = {S::kInfos, sizeof infos[0], n * sizeof infos[0]};

    auto fbs_input = [&] {
        auto in = std::make_unique<fbs::ClusterInputInfoT>();
        in->max_acceleration_structure_count = n;
        in->op_type = info.input.opType;
        in->op_mode = info.input.opMode;
        fbs::TriangleClusterInputT t;
        t.vertex_format = tri.vertexFormat;
        t.max_cluster_unique_geometry_count = 1;
        t.max_cluster_triangle_count = max_tris;
        t.max_cluster_vertex_count = max_verts;
        t.max_total_triangle_count = tri.maxTotalTriangleCount;
        t.max_total_vertex_count = tri.maxTotalVertexCount;
        in->op_input.Set(std::move(t));
        return in;
    };
    if (call.query) {
        fbs::GetClusterBuildSizesT q;
        q.input = fbs_input();
        q.acceleration_structure_size = call.query_answer;
        q.build_scratch_size = call.query_scratch;
        check(writer_->append(record(std::move(q))));
    }

    std::vector<std::pair<uint64_t, std::vector<uint8_t>>> inputs = {
        {S::kInfos, bytes_of(infos.data(), n * sizeof infos[0])},
        {S::kIndices, bytes_of(indices.data(), indices.size() * 4)},
        {S::kVertices, bytes_of(vertices.data(), vertices.size() * 4)}};
    if (explicit_mode) {
        std::vector<uint64_t> slots(n);
        std::vector<uint32_t> room(n, 1024);
        for (uint32_t i = 0; i < n; ++i) slots[i] = call.dst + i * 1024ull;
        inputs.emplace_back(call.arrays, bytes_of(slots.data(), n * 8ull));
        inputs.emplace_back(call.arrays + 0x200, bytes_of(room.data(), n * 4ull));
    }
    for (const auto& [address, bytes] : inputs)
        std::memcpy(mirror_->image.write_bytes(address, bytes.size(), {}).data(), bytes.data(), bytes.size());
    engine::ExecuteOptions options;
    options.directory = &mirror_->directory;
    const engine::ExecutionRecord r = engine::execute(info, mirror_->image, options);
    if (!r.findings.empty()) throw std::runtime_error("scene build has findings: " + r.findings[0].message);
    built.implicit_used = r.implicit_bytes_used;
    built.scratch_used = r.scratch_bytes_used;
    std::vector<uint64_t> addresses(n);
    std::vector<uint32_t> driver_sizes(n);
    for (uint32_t i = 0; i < n; ++i) {
        built.engine_sizes.push_back(r.ops[i].dst_size);
        addresses[i] = r.ops[i].dst_address;
        driver_sizes[i] = static_cast<uint32_t>(r.ops[i].dst_size) + call.driver_extra_bytes;
    }

    fbs::CmdBuildClusterAccelerationStructureIndirectT b;
    b.command_buffer = command_buffer_;
    b.input = fbs_input();
    b.dst_implicit_data = info.dstImplicitData;
    b.scratch_data = info.scratchData;
    b.dst_addresses_array = std::make_unique<fbs::StridedDeviceAddressRegion>(call.arrays, 8, n * 8ull);
    b.dst_sizes_array = std::make_unique<fbs::StridedDeviceAddressRegion>(call.arrays + 0x200, 4, n * 4ull);
    b.src_infos_array = std::make_unique<fbs::StridedDeviceAddressRegion>(S::kInfos, sizeof infos[0], n * sizeof infos[0]);
    fbs::MemorySnapshot snap;
    for (const auto& [address, bytes] : inputs) {
        check(writer_->snapshot(0, 0, address, bytes.data(), bytes.size(), &snap));
        b.inputs.push_back(snap);
    }
    if (implicit) {
        check(writer_->snapshot(0, 0, call.arrays, addresses.data(), n * 8ull, &snap));
        b.outputs.push_back(snap);
    }
    if (!explicit_mode) {
        check(writer_->snapshot(0, 0, call.arrays + 0x200, driver_sizes.data(), n * 4ull, &snap));
        b.outputs.push_back(snap);
    }
    check(writer_->append(record(std::move(b))));
    return built;
}

void AnalyzeSceneWriter::timestamp(uint64_t ticks) {
    fbs::GpuTimestampT t;
    t.command_buffer = command_buffer_;
    t.query_pool = 0x77;
    t.stage_mask = VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR;
    t.ticks = ticks;
    t.ticks_valid = true;
    check(writer_->append(record(t)));
}

void AnalyzeSceneWriter::build_to_build_barrier() {
    fbs::CmdPipelineBarrierT b;
    b.command_buffer = command_buffer_;
    b.version = 2;
    b.dependency = std::make_unique<fbs::DependencyT>();
    const uint64_t as = VK_ACCESS_2_ACCELERATION_STRUCTURE_READ_BIT_KHR | VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR;
    b.dependency->memory_barriers.emplace_back(VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR, as,
                                               VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR, as);
    check(writer_->append(record(std::move(b))));
}

void AnalyzeSceneWriter::copy_buffer() {
    fbs::CmdCopyBufferT c;
    c.command_buffer = command_buffer_;
    c.version = 1;
    c.src_buffer = 0x2004;  // the arrays' buffer, past the arrays
    c.dst_buffer = 0x2004;
    c.regions.emplace_back(0x2000, 0x2800, 0x100);
    check(writer_->append(record(std::move(c))));
}

static std::unique_ptr<fbs::GeometryNVT> nv_triangles(uint32_t index_count) {
    auto g = std::make_unique<fbs::GeometryNVT>();
    g->geometry_type = VK_GEOMETRY_TYPE_TRIANGLES_NV;
    g->triangles = std::make_unique<fbs::GeometryTrianglesNV>(AnalyzeScene::kVertexBuffer, 0, 10, VK_FORMAT_R32G32B32_SFLOAT, 12,
                                                              AnalyzeScene::kIndexBuffer, 0x8000, index_count,
                                                              VK_INDEX_TYPE_UINT32, 0, 0);
    return g;
}

void AnalyzeSceneWriter::nv_build(uint32_t index_count, uint64_t object_bytes, uint64_t scratch_bytes) {
    if (!nv_declared_) {
        fbs::AccelerationStructureCreateT c;
        c.acceleration_structure = AnalyzeScene::kNvObject;
        c.api = 0;
        c.type = VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_NV;
        c.info = std::make_unique<fbs::AccelerationStructureInfoNVT>();  // room for the build's geometry
        c.info->type = VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_NV;
        c.info->geometries.push_back(nv_triangles(index_count));
        check(writer_->append(record(std::move(c))));
        for (auto [type, size] : {std::pair<uint32_t, uint64_t>{VK_ACCELERATION_STRUCTURE_MEMORY_REQUIREMENTS_TYPE_OBJECT_NV, object_bytes},
                                  {VK_ACCELERATION_STRUCTURE_MEMORY_REQUIREMENTS_TYPE_BUILD_SCRATCH_NV, scratch_bytes}}) {
            fbs::AccelerationStructureMemoryRequirementsNVT q;
            q.acceleration_structure = AnalyzeScene::kNvObject;
            q.type = type;
            q.size = size;
            q.alignment = 256;
            check(writer_->append(record(std::move(q))));
        }
        fbs::AccelerationStructureBindMemoryT bind;  // an unbound dst is VUID 07787
        bind.acceleration_structure = AnalyzeScene::kNvObject;
        bind.memory = 0x3001;
        check(writer_->append(record(std::move(bind))));
        nv_declared_ = true;
    }
    fbs::CmdBuildAccelerationStructureNVT b;
    b.command_buffer = command_buffer_;
    b.info = std::make_unique<fbs::AccelerationStructureInfoNVT>();
    b.info->type = VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_NV;
    b.info->geometries.push_back(nv_triangles(index_count));
    b.dst = AnalyzeScene::kNvObject;
    b.scratch = AnalyzeScene::kPoolBuffer;
    b.scratch_offset = 0x38000;
    check(writer_->append(record(std::move(b))));
}

// Another driver's serialized object (UUIDs not the engine's): opaque to the replay, but its
// header must hold together (sizes, no handles) or the replay reports VUID 04960.
static std::vector<uint8_t> foreign_serialized_blob(uint64_t serialized_bytes, uint64_t object_bytes) {
    std::vector<uint8_t> blob(std::max<uint64_t>(serialized_bytes, 56), 0x5a);
    const uint64_t header[3] = {blob.size(), object_bytes, 0};  // serialized, deserialized size, handle count
    std::memcpy(blob.data() + 32, header, sizeof header);
    return blob;
}

void AnalyzeSceneWriter::deserialize(uint64_t serialized_bytes, uint64_t object_bytes) {
    if (!khr_declared_) {
        fbs::AccelerationStructureCreateT c;
        c.acceleration_structure = AnalyzeScene::kKhrObject;
        c.api = 1;
        c.type = VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR;
        c.buffer = AnalyzeScene::kAsBuffer;
        c.offset = 0x1000;
        c.size = object_bytes;
        check(writer_->append(record(std::move(c))));
        khr_declared_ = true;
    }
    std::vector<uint8_t> serialized = foreign_serialized_blob(serialized_bytes, object_bytes);
    fbs::CmdCopyMemoryToAccelerationStructureT k;
    k.command_buffer = command_buffer_;
    k.src_address = AnalyzeScene::kSerialized;
    k.dst = AnalyzeScene::kKhrObject;
    k.mode = VK_COPY_ACCELERATION_STRUCTURE_MODE_DESERIALIZE_KHR;
    fbs::MemorySnapshot snap;
    check(writer_->snapshot(0, 0, AnalyzeScene::kSerialized, serialized.data(), serialized.size(), &snap));
    k.inputs.push_back(snap);
    check(writer_->append(record(std::move(k))));
}

void AnalyzeSceneWriter::calibrate(uint64_t gpu_ticks, uint64_t host_ns, uint64_t max_deviation_ns) {
    fbs::CalibratedTimestampsT c;
    c.gpu_ticks = gpu_ticks;
    c.cpu_nanoseconds = host_ns;
    c.max_deviation_ns = max_deviation_ns;
    check(writer_->append(record(c)));
}

void AnalyzeSceneWriter::submit() {
    fbs::CommandBufferEndT end;
    end.command_buffer = command_buffer_;
    check(writer_->append(record(end)));
    fbs::QueueSubmitT submit;
    submit.queue = kQueue;
    submit.version = 2;
    auto batch = std::make_unique<fbs::SubmitBatchT>();
    batch->command_buffers.push_back(command_buffer_);
    submit.batches.push_back(std::move(batch));
    submit.fence = kFence;
    submit.submission_index = writer_->next_submission_index();
    check(writer_->append(record(std::move(submit))));
    fbs::FenceWaitT wait;
    wait.fences.push_back(kFence);
    wait.wait_all = true;
    check(writer_->append(record(std::move(wait))));
    ++command_buffer_;
    begin();
}

traces::TraceWriterStats AnalyzeSceneWriter::finish() {
    fbs::CommandBufferEndT end;
    end.command_buffer = command_buffer_;
    check(writer_->append(record(end)));
    check(writer_->finish());
    return writer_->stats();
}

}  // namespace clastrace::test
