// SPDX-License-Identifier: Apache-2.0
#include "analyze_scene.h"

#include <clastrace/trace_building/cluster_records.h>
#include <clastrace/trace_building/cluster_structs.h>
#include <clastrace/trace_building/command_records.h>
#include <clastrace/trace_building/trace_header.h>

#include <algorithm>
#include <cstring>
#include <stdexcept>

namespace clastrace::test {

namespace tb = trace_building;

namespace {
constexpr uint64_t kQueue = 0x9001, kFence = 0xfe1, kMemory = 0x1001;

// A driver trace: captured sizes may differ from the engine's.
fbs::TraceHeaderT driver_header(float timestamp_period_ns) {
    fbs::TraceHeaderT h = tb::trace_header("test driver", "NVIDIA", "analyze_cli_tests");
    h.device->timestamp_period_ns = timestamp_period_ns;
    return h;
}
}  // namespace

AnalyzeSceneWriter::~AnalyzeSceneWriter() = default;

void AnalyzeSceneWriter::add_buffer(uint64_t handle, uint64_t address, uint64_t size,
                                    uint64_t usage) {
    writer_.buffer(handle, address, size, usage, kMemory, address - 0x10000000);
    mirror_.add_buffer(address, size, usage);
}

AnalyzeSceneWriter::AnalyzeSceneWriter(const std::string& path, float timestamp_period_ns)
    : writer_(path, driver_header(timestamp_period_ns)) {
    const uint64_t sda = VK_BUFFER_USAGE_SHADER_DEVICE_ADDRESS_BIT;
    const uint64_t input =
        sda | VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_BIT_KHR;
    const uint64_t storage = sda | VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_STORAGE_BIT_KHR |
                             VK_BUFFER_USAGE_STORAGE_BUFFER_BIT;
    using S = AnalyzeScene;
    add_buffer(S::kVertexBuffer, S::kVertices, 0x10000, input);
    add_buffer(S::kIndexBuffer, S::kIndices, 0x10000, input);
    add_buffer(0x2003, S::kInfos, 0x4000, input);
    add_buffer(0x2004, S::kArrays, 0x4000,
               storage | VK_BUFFER_USAGE_TRANSFER_SRC_BIT | VK_BUFFER_USAGE_TRANSFER_DST_BIT);
    add_buffer(S::kPoolBuffer, S::kPool, S::kPoolSize,
               storage | VK_BUFFER_USAGE_TRANSFER_SRC_BIT | VK_BUFFER_USAGE_TRANSFER_DST_BIT |
                   VK_BUFFER_USAGE_RAY_TRACING_BIT_NV);  // also the NV build's scratch
    add_buffer(0x2007, S::kSerialized, 0x1000, input);
    add_buffer(S::kAsBuffer, S::kAsStorage, 0x10000, storage);
    begin();
}

void AnalyzeSceneWriter::begin() {
    writer_.append(
        tb::command_buffer_begin(command_buffer_, VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT));
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
        infos[c] = tb::triangle_cluster_info(10 + c, t, v, S::kIndices + indices.size() * 4, 4,
                                             S::kVertices + vertices.size() * 4);
        infos[c].positionTruncateBitCount = call.truncate_bits;
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
    const auto tri =
        tb::triangle_cluster_limits(max_tris, max_verts, static_cast<uint32_t>(built.triangles),
                                    static_cast<uint32_t>(built.vertices));
    auto info = tb::cluster_commands(tb::cluster_op_input(n, &tri, call.mode));
    const bool implicit =
        call.mode == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV;
    const bool explicit_mode =
        call.mode == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_EXPLICIT_DESTINATIONS_NV;
    info.dstImplicitData = implicit ? call.dst : 0;
    info.scratchData = call.scratch;
    info.dstAddressesArray = {call.arrays, 8, n * 8ull};
    info.dstSizesArray = {call.arrays + 0x200, 4, n * 4ull};
    info.srcInfosArray = {S::kInfos, sizeof infos[0], n * sizeof infos[0]};

    if (call.query) {
        fbs::GetClusterBuildSizesT q;
        q.input = tb::cluster_input(info.input);
        q.acceleration_structure_size = call.query_answer;
        q.build_scratch_size = call.query_scratch;
        writer_.append(std::move(q));
    }

    std::vector<std::pair<uint64_t, std::vector<uint8_t>>> inputs = {
        {S::kInfos, tb::bytes_of(infos)},
        {S::kIndices, tb::bytes_of(indices)},
        {S::kVertices, tb::bytes_of(vertices)}};
    if (explicit_mode) {
        std::vector<uint64_t> slots(n);
        std::vector<uint32_t> room(n, 1024);
        for (uint32_t i = 0; i < n; ++i) slots[i] = call.dst + i * 1024ull;
        inputs.emplace_back(call.arrays, tb::bytes_of(slots));
        inputs.emplace_back(call.arrays + 0x200, tb::bytes_of(room));
    }
    for (const auto& [address, bytes] : inputs) mirror_.write(address, bytes);
    const engine::ExecutionRecord r = mirror_.execute(info);
    if (!r.findings.empty())
        throw std::runtime_error("scene build has findings: " + r.findings[0].message);
    built.implicit_used = r.implicit_bytes_used;
    built.scratch_used = r.scratch_bytes_used;
    std::vector<uint64_t> addresses(n);
    std::vector<uint32_t> driver_sizes(n);
    for (uint32_t i = 0; i < n; ++i) {
        built.engine_sizes.push_back(r.ops[i].dst_size);
        addresses[i] = r.ops[i].dst_address;
        driver_sizes[i] = static_cast<uint32_t>(r.ops[i].dst_size) + call.driver_extra_bytes;
    }

    fbs::CmdBuildClusterAccelerationStructureIndirectT b = tb::cluster_build(command_buffer_, info);
    for (const auto& [address, bytes] : inputs)
        b.inputs.push_back(writer_.snapshot(address, bytes));
    if (implicit) b.outputs.push_back(writer_.snapshot(call.arrays, tb::bytes_of(addresses)));
    if (!explicit_mode)
        b.outputs.push_back(writer_.snapshot(call.arrays + 0x200, tb::bytes_of(driver_sizes)));
    writer_.append(std::move(b));
    return built;
}

void AnalyzeSceneWriter::timestamp(uint64_t ticks) {
    fbs::GpuTimestampT t;
    t.command_buffer = command_buffer_;
    t.query_pool = 0x77;
    t.stage_mask = VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR;
    t.ticks = ticks;
    t.ticks_valid = true;
    writer_.append(t);
}

void AnalyzeSceneWriter::build_to_build_barrier() {
    const uint64_t as = VK_ACCESS_2_ACCELERATION_STRUCTURE_READ_BIT_KHR |
                        VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR;
    writer_.append(tb::memory_barrier(command_buffer_,
                                      VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR, as,
                                      VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                                      as));
}

void AnalyzeSceneWriter::copy_buffer() {
    fbs::CmdCopyBufferT c;
    c.command_buffer = command_buffer_;
    c.version = 1;
    c.src_buffer = 0x2004;  // the arrays' buffer, past the arrays
    c.dst_buffer = 0x2004;
    c.regions.emplace_back(0x2000, 0x2800, 0x100);
    writer_.append(std::move(c));
}

static std::unique_ptr<fbs::GeometryNVT> nv_triangles(uint32_t index_count) {
    auto g = std::make_unique<fbs::GeometryNVT>();
    g->geometry_type = VK_GEOMETRY_TYPE_TRIANGLES_NV;
    g->triangles =
        std::make_unique<fbs::GeometryTrianglesNV>(AnalyzeScene::kVertexBuffer, 0, 10,
                                                   VK_FORMAT_R32G32B32_SFLOAT, 12,
                                                   AnalyzeScene::kIndexBuffer, 0x8000, index_count,
                                                   VK_INDEX_TYPE_UINT32, 0, 0);
    return g;
}

void AnalyzeSceneWriter::nv_build(uint32_t index_count, uint64_t object_bytes,
                                  uint64_t scratch_bytes) {
    if (!nv_declared_) {
        fbs::AccelerationStructureCreateT c;
        c.acceleration_structure = AnalyzeScene::kNvObject;
        c.api = 0;
        c.type = VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_NV;
        c.info =
            std::make_unique<fbs::AccelerationStructureInfoNVT>();  // room for the build's geometry
        c.info->type = VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_NV;
        c.info->geometries.push_back(nv_triangles(index_count));
        writer_.append(std::move(c));
        for (auto [type, size] :
             {std::pair<uint32_t, uint64_t>{
                  VK_ACCELERATION_STRUCTURE_MEMORY_REQUIREMENTS_TYPE_OBJECT_NV, object_bytes},
              {VK_ACCELERATION_STRUCTURE_MEMORY_REQUIREMENTS_TYPE_BUILD_SCRATCH_NV,
               scratch_bytes}}) {
            fbs::AccelerationStructureMemoryRequirementsNVT q;
            q.acceleration_structure = AnalyzeScene::kNvObject;
            q.type = type;
            q.size = size;
            q.alignment = 256;
            writer_.append(std::move(q));
        }
        fbs::AccelerationStructureBindMemoryT bind;  // an unbound dst is VUID 07787
        bind.acceleration_structure = AnalyzeScene::kNvObject;
        bind.memory = 0x3001;
        writer_.append(std::move(bind));
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
    writer_.append(std::move(b));
}

// Another driver's serialized object (UUIDs not the engine's): opaque to the replay, but its
// header must hold together (sizes, no handles) or the replay reports VUID 04960.
static std::vector<uint8_t> foreign_serialized_blob(uint64_t serialized_bytes,
                                                    uint64_t object_bytes) {
    std::vector<uint8_t> blob(std::max<uint64_t>(serialized_bytes, 56), 0x5a);
    const uint64_t header[3] = {blob.size(), object_bytes,
                                0};  // serialized, deserialized size, handle count
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
        writer_.append(std::move(c));
        khr_declared_ = true;
    }
    std::vector<uint8_t> serialized = foreign_serialized_blob(serialized_bytes, object_bytes);
    fbs::CmdCopyMemoryToAccelerationStructureT k;
    k.command_buffer = command_buffer_;
    k.src_address = AnalyzeScene::kSerialized;
    k.dst = AnalyzeScene::kKhrObject;
    k.mode = VK_COPY_ACCELERATION_STRUCTURE_MODE_DESERIALIZE_KHR;
    k.inputs.push_back(writer_.snapshot(AnalyzeScene::kSerialized, serialized));
    writer_.append(std::move(k));
}

void AnalyzeSceneWriter::calibrate(uint64_t gpu_ticks, uint64_t host_ns,
                                   uint64_t max_deviation_ns) {
    fbs::CalibratedTimestampsT c;
    c.gpu_ticks = gpu_ticks;
    c.cpu_nanoseconds = host_ns;
    c.max_deviation_ns = max_deviation_ns;
    writer_.append(c);
}

void AnalyzeSceneWriter::submit() {
    writer_.end_and_submit(kQueue, command_buffer_, kFence);
    writer_.wait_fence(kFence);
    ++command_buffer_;
    begin();
}

traces::TraceWriterStats AnalyzeSceneWriter::finish() {
    writer_.append(tb::command_buffer_end(command_buffer_));
    return writer_.finish();
}

}  // namespace clastrace::test
