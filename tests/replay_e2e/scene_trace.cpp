#include "scene_trace.h"

#include <clastrace/engine/execute.h>
#include <clastrace/engine/memory_image.h>
#include <clastrace/engine/object_directory.h>

#include <cstring>
#include <stdexcept>

namespace clastrace::test {

namespace {
constexpr uint64_t kFirstCommandBuffer = 0xc0de, kQueue = 0x9001, kFence = 0xfe1, kMemory = 0x1001, kHostMemory = 0x1002;
constexpr uint64_t kStaging = 0x2100;
constexpr uint32_t kClusters = 2, kGrid = 3, kVerts = kGrid * kGrid, kTris = (kGrid - 1) * (kGrid - 1) * 2;

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

struct SceneTrace::Mirror {
    engine::MemoryImage image;
    engine::ObjectDirectory directory;
};

SceneTrace::~SceneTrace() = default;

void SceneTrace::add_buffer(uint64_t handle, uint64_t address, uint64_t size, uint64_t usage, uint64_t memory,
                            uint64_t offset) {
    fbs::BufferCreateT c;
    c.buffer = handle;
    c.size = size;
    c.usage = usage;
    check(writer_->append(record(c)));
    fbs::BufferBindMemoryT b;
    b.buffer = handle;
    b.memory = memory;
    b.memory_offset = offset;
    b.device_address = address;
    check(writer_->append(record(b)));
    if (address) mirror_->image.add_region(address, size, static_cast<VkBufferUsageFlags>(usage), "mirror");
}

SceneTrace::SceneTrace(const std::string& path, bool engine_device, uint64_t scratch_size)
    : mirror_(std::make_unique<Mirror>()), scratch_size_(scratch_size), engine_device_(engine_device),
      command_buffer_(kFirstCommandBuffer) {
    fbs::TraceHeaderT h;
    h.device = std::make_unique<fbs::DeviceInfoT>();
    h.device->name = engine_device ? "clastrace engine" : "test driver";
    h.device->driver_name = engine_device ? "clastrace engine" : "NVIDIA";
    h.device->cluster_properties = std::make_unique<fbs::ClusterPropertiesT>();
    auto& p = *h.device->cluster_properties;
    p.max_vertices_per_cluster = 256;
    p.max_triangles_per_cluster = 256;
    p.cluster_scratch_byte_alignment = 128;
    p.cluster_byte_alignment = 128;
    p.cluster_template_byte_alignment = 32;
    p.cluster_bottom_level_byte_alignment = 256;
    p.cluster_template_bounds_byte_alignment = 32;
    p.max_cluster_geometry_index = 16777215;
    h.capture = std::make_unique<fbs::CaptureSettingsT>();
    h.capture->capture_tool = "replay_e2e_tests";
    traces::TraceError e;
    traces::TraceWriterOptions o;
    o.sync_on_finish = false;
    writer_ = traces::TraceWriter::create(path, h, o, &e);
    check(e);

    const uint64_t sda = VK_BUFFER_USAGE_SHADER_DEVICE_ADDRESS_BIT;
    const uint64_t input = sda | VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_BIT_KHR;
    const uint64_t as_storage = sda | VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_STORAGE_BIT_KHR | VK_BUFFER_USAGE_STORAGE_BUFFER_BIT;
    using B = SceneBuffers;
    add_buffer(0x2001, B::kVertices, 4096, input, kMemory, 0);
    add_buffer(0x2002, B::kIndices, 4096, input, kMemory, 0x10000);
    add_buffer(0x2003, B::kInfos, 4096, input | VK_BUFFER_USAGE_TRANSFER_DST_BIT, kMemory, 0x20000);
    add_buffer(0x2004, B::kDst, 0x10000, as_storage, kMemory, 0x100000);
    add_buffer(0x2005, B::kDst2, 0x10000, as_storage, kMemory, 0x200000);
    add_buffer(0x2006, B::kAddresses, 256, as_storage, kMemory, 0x30000);
    add_buffer(0x2007, B::kAddresses2, 256, as_storage, kMemory, 0x31000);
    add_buffer(0x2008, B::kSizes, 256, as_storage, kMemory, 0x32000);
    add_buffer(0x2009, B::kSizes2, 256, as_storage, kMemory, 0x33000);
    add_buffer(0x200a, B::kScratch, scratch_size, as_storage, kMemory, 0x40000);
    add_buffer(0x200b, B::kBlasInfos, 4096, input, kMemory, 0x50000);
    add_buffer(0x200c, B::kBlasDst, 0x10000, as_storage, kMemory, 0x300000);
    add_buffer(kStaging, 0, 4096, VK_BUFFER_USAGE_TRANSFER_SRC_BIT, kHostMemory, 0);

    for (uint32_t c = 0; c < kClusters; ++c)
        for (uint32_t y = 0; y < kGrid; ++y)
            for (uint32_t x = 0; x < kGrid; ++x) {
                vertices_.push_back(float(x) + 4.0f * c);
                vertices_.push_back(float(y));
                vertices_.push_back(0.25f * float(x * y));
            }
    for (uint32_t y = 0; y + 1 < kGrid; ++y)
        for (uint32_t x = 0; x + 1 < kGrid; ++x) {
            uint8_t a = uint8_t(y * kGrid + x), b = uint8_t(a + 1), c = uint8_t(a + kGrid), d = uint8_t(c + 1);
            for (uint8_t v : {a, b, c, b, d, c}) indices_.push_back(v);
        }
    infos.resize(kClusters);
    for (uint32_t c = 0; c < kClusters; ++c) {
        auto& i = infos[c];
        std::memset(&i, 0, sizeof i);
        i.clusterID = 100 + c;
        i.triangleCount = kTris;
        i.vertexCount = kVerts;
        i.indexType = VK_CLUSTER_ACCELERATION_STRUCTURE_INDEX_FORMAT_8BIT_NV;
        i.indexBufferStride = 1;
        i.vertexBufferStride = 12;
        i.indexBuffer = B::kIndices;
        i.vertexBuffer = B::kVertices + c * kVerts * 12;
    }
    fbs::CommandBufferBeginT begin;
    begin.command_buffer = command_buffer_;
    check(writer_->append(record(begin)));
}

void SceneTrace::copy_infos() {
    fbs::CmdCopyBufferT copy;
    copy.command_buffer = command_buffer_;
    copy.version = 1;
    copy.src_buffer = kStaging;
    copy.dst_buffer = 0x2003;
    const uint64_t n = infos.size() * sizeof infos[0];
    copy.regions.emplace_back(0, 0, n);
    fbs::MemorySnapshot snap;
    check(writer_->snapshot(kStaging, 0, 0, infos.data(), n, &snap));
    copy.inputs.push_back(snap);
    check(writer_->append(record(std::move(copy))));
}

void SceneTrace::barrier(uint64_t src_stage, uint64_t src_access, uint64_t dst_stage, uint64_t dst_access) {
    fbs::CmdPipelineBarrierT b;
    b.command_buffer = command_buffer_;
    b.version = 2;
    b.dependency = std::make_unique<fbs::DependencyT>();
    b.dependency->memory_barriers.emplace_back(src_stage, src_access, dst_stage, dst_access);
    check(writer_->append(record(std::move(b))));
}

void SceneTrace::barrier_v1(uint32_t src_stage, uint32_t src_access, uint32_t dst_stage, uint32_t dst_access) {
    fbs::CmdPipelineBarrierT b;
    b.command_buffer = command_buffer_;
    b.version = 1;
    b.src_stage_mask = src_stage;
    b.dst_stage_mask = dst_stage;
    b.dependency = std::make_unique<fbs::DependencyT>();
    b.dependency->memory_barriers.emplace_back(src_stage, src_access, dst_stage, dst_access);
    check(writer_->append(record(std::move(b))));
}

void SceneTrace::set_event(uint64_t event, uint64_t src_stage, uint64_t src_access, uint64_t dst_stage, uint64_t dst_access) {
    fbs::CmdSetEventT e;
    e.command_buffer = command_buffer_;
    e.event = event;
    e.version = 2;
    e.dependency = std::make_unique<fbs::DependencyT>();
    e.dependency->memory_barriers.emplace_back(src_stage, src_access, dst_stage, dst_access);
    check(writer_->append(record(std::move(e))));
}

void SceneTrace::wait_event(uint64_t event, uint64_t src_stage, uint64_t src_access, uint64_t dst_stage, uint64_t dst_access) {
    fbs::CmdWaitEventsT w;
    w.command_buffer = command_buffer_;
    w.version = 2;
    w.events.push_back(event);
    auto dep = std::make_unique<fbs::DependencyT>();
    dep->memory_barriers.emplace_back(src_stage, src_access, dst_stage, dst_access);
    w.dependencies.push_back(std::move(dep));
    check(writer_->append(record(std::move(w))));
}

void SceneTrace::emit_build(const VkClusterAccelerationStructureCommandsInfoNV& info, const BuildCall& call,
                            std::vector<std::pair<uint64_t, std::vector<uint8_t>>> inputs, uint64_t shift,
                            const std::vector<std::pair<uint64_t, std::vector<uint8_t>>>& mirror_patch) {
    for (const auto& list : {inputs, mirror_patch})
        for (const auto& [address, bytes] : list)
            std::memcpy(mirror_->image.write_bytes(address, bytes.size(), {}).data(), bytes.data(), bytes.size());
    engine::ExecuteOptions options;
    options.directory = &mirror_->directory;
    engine::ExecutionRecord r = engine::execute(info, mirror_->image, options);

    fbs::CmdBuildClusterAccelerationStructureIndirectT b;
    b.command_buffer = command_buffer_;
    b.input = std::make_unique<fbs::ClusterInputInfoT>();
    b.input->max_acceleration_structure_count = info.input.maxAccelerationStructureCount;
    b.input->op_type = info.input.opType;
    b.input->op_mode = info.input.opMode;
    if (info.input.opType == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV) {
        fbs::ClustersBottomLevelInputT in;
        in.max_total_cluster_count = info.input.opInput.pClustersBottomLevel->maxTotalClusterCount;
        in.max_cluster_count_per_acceleration_structure = info.input.opInput.pClustersBottomLevel->maxClusterCountPerAccelerationStructure;
        b.input->op_input.Set(std::move(in));
    } else if (info.input.opType == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV) {
        fbs::MoveObjectsInputT in;
        in.type = info.input.opInput.pMoveObjects->type;
        in.no_move_overlap = info.input.opInput.pMoveObjects->noMoveOverlap;
        in.max_moved_bytes = info.input.opInput.pMoveObjects->maxMovedBytes;
        b.input->op_input.Set(std::move(in));
    } else {
        const auto& t = *info.input.opInput.pTriangleClusters;
        fbs::TriangleClusterInputT in;
        in.vertex_format = t.vertexFormat;
        in.max_cluster_unique_geometry_count = t.maxClusterUniqueGeometryCount;
        in.max_cluster_triangle_count = t.maxClusterTriangleCount;
        in.max_cluster_vertex_count = t.maxClusterVertexCount;
        in.max_total_triangle_count = t.maxTotalTriangleCount;
        in.max_total_vertex_count = t.maxTotalVertexCount;
        b.input->op_input.Set(std::move(in));
    }
    b.dst_implicit_data = info.dstImplicitData;
    b.scratch_data = info.scratchData;
    b.dst_addresses_array = std::make_unique<fbs::StridedDeviceAddressRegion>(info.dstAddressesArray.deviceAddress,
                                                                              info.dstAddressesArray.stride, info.dstAddressesArray.size);
    b.dst_sizes_array = std::make_unique<fbs::StridedDeviceAddressRegion>(info.dstSizesArray.deviceAddress,
                                                                          info.dstSizesArray.stride, info.dstSizesArray.size);
    b.src_infos_array = std::make_unique<fbs::StridedDeviceAddressRegion>(info.srcInfosArray.deviceAddress,
                                                                          info.srcInfosArray.stride, info.srcInfosArray.size);
    fbs::MemorySnapshot snap;
    for (auto& [address, bytes] : inputs) {
        check(writer_->snapshot(0, 0, address, bytes.data(), bytes.size(), &snap));
        b.inputs.push_back(snap);
    }
    if (call.capture_outputs) {
        const uint64_t n = info.input.maxAccelerationStructureCount;
        std::vector<uint64_t> addresses(n);
        for (uint64_t i = 0; i < n && i < r.ops.size(); ++i) addresses[i] = r.ops[i].dst_address ? r.ops[i].dst_address + shift : 0;
        check(writer_->snapshot(0, 0, info.dstAddressesArray.deviceAddress, addresses.data(), n * 8, &snap));
        b.outputs.push_back(snap);
        auto sizes = mirror_->image.read_bytes(info.dstSizesArray.deviceAddress, n * 4, {});
        check(writer_->snapshot(0, 0, info.dstSizesArray.deviceAddress, sizes.data(), n * 4, &snap));
        b.outputs.push_back(snap);
        if (engine_device_ && r.implicit_bytes_used) {
            auto objects = mirror_->image.read_bytes(info.dstImplicitData, r.implicit_bytes_used, {});
            std::vector<uint8_t> copy = bytes_of(objects.data(), objects.size());
            if (call.corrupt_output_byte) copy[call.corrupt_output_byte % copy.size()] ^= 0x40;
            check(writer_->snapshot(0, 0, info.dstImplicitData, copy.data(), copy.size(), &snap));
            b.outputs.push_back(snap);
        }
    }
    check(writer_->append(record(std::move(b))));
}

void SceneTrace::build(const BuildCall& call) {
    VkClusterAccelerationStructureTriangleClusterInputNV tri{};
    tri.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_TRIANGLE_CLUSTER_INPUT_NV;
    tri.vertexFormat = VK_FORMAT_R32G32B32_SFLOAT;
    tri.maxClusterUniqueGeometryCount = 1;
    tri.maxClusterTriangleCount = kTris;
    tri.maxClusterVertexCount = kVerts;
    tri.maxTotalTriangleCount = kTris * kClusters;
    tri.maxTotalVertexCount = kVerts * kClusters;
    VkClusterAccelerationStructureCommandsInfoNV info{};
    info.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_COMMANDS_INFO_NV;
    info.input.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_INPUT_INFO_NV;
    info.input.maxAccelerationStructureCount = static_cast<uint32_t>(infos.size());
    info.input.opType = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV;
    info.input.opMode = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV;
    info.input.opInput.pTriangleClusters = &tri;
    info.dstImplicitData = call.dst;
    info.scratchData = call.scratch;
    info.dstAddressesArray = {call.addresses, 8, infos.size() * 8};
    info.dstSizesArray = {call.sizes, 4, infos.size() * 4};
    info.srcInfosArray = {SceneBuffers::kInfos, sizeof infos[0], infos.size() * sizeof infos[0]};
    std::vector<VkClusterAccelerationStructureBuildTriangleClusterInfoNV> call_infos = infos;
    for (size_t c = 0; c < call_infos.size(); ++c)
        if (call_infos[c].clusterID != 0xFFFFFFFFu) call_infos[c].clusterID = call.first_cluster_id + uint32_t(c);
    emit_build(info, call,
               {{SceneBuffers::kInfos, bytes_of(call_infos.data(), call_infos.size() * sizeof call_infos[0])},
                {SceneBuffers::kIndices, indices_},
                {SceneBuffers::kVertices, bytes_of(vertices_.data(), vertices_.size() * 4)}},
               engine_device_ ? 0 : driver_address_shift);
}

void SceneTrace::build_blas(const std::vector<uint64_t>& cluster_addresses) {
    VkClusterAccelerationStructureClustersBottomLevelInputNV in{};
    in.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_CLUSTERS_BOTTOM_LEVEL_INPUT_NV;
    in.maxTotalClusterCount = static_cast<uint32_t>(cluster_addresses.size());
    in.maxClusterCountPerAccelerationStructure = in.maxTotalClusterCount;
    VkClusterAccelerationStructureCommandsInfoNV info{};
    info.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_COMMANDS_INFO_NV;
    info.input.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_INPUT_INFO_NV;
    info.input.maxAccelerationStructureCount = 1;
    info.input.opType = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV;
    info.input.opMode = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV;
    info.input.opInput.pClustersBottomLevel = &in;
    info.dstImplicitData = SceneBuffers::kBlasDst;
    info.scratchData = SceneBuffers::kScratch;
    info.dstAddressesArray = {SceneBuffers::kAddresses2, 8, 8};
    info.dstSizesArray = {SceneBuffers::kSizes2, 4, 4};
    info.srcInfosArray = {SceneBuffers::kBlasInfos, 16, 16};
    VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV blas{};
    blas.clusterReferencesCount = static_cast<uint32_t>(cluster_addresses.size());
    blas.clusterReferencesStride = 8;
    blas.clusterReferences = SceneBuffers::kBlasInfos + 64;
    // The mirror runs on the engine's addresses; the trace holds the captured ones.
    const uint64_t shift = engine_device_ ? 0 : driver_address_shift;
    std::vector<uint64_t> mirror_refs;
    for (uint64_t a : cluster_addresses) mirror_refs.push_back(a - shift);
    std::vector<uint8_t> captured(64 + cluster_addresses.size() * 8, 0);
    std::memcpy(captured.data(), &blas, sizeof blas);
    std::memcpy(captured.data() + 64, cluster_addresses.data(), cluster_addresses.size() * 8);
    BuildCall call;
    call.capture_outputs = false;
    emit_build(info, call, {{SceneBuffers::kBlasInfos, captured}}, shift,
               {{blas.clusterReferences, bytes_of(mirror_refs.data(), mirror_refs.size() * 8)}});
}

void SceneTrace::wait_fence(uint64_t fence) {
    fbs::FenceWaitT wait;
    wait.fences.push_back(fence);
    wait.wait_all = true;
    check(writer_->append(record(std::move(wait))));
}

void SceneTrace::observe(uint64_t address, const std::vector<uint8_t>& bytes) {
    fbs::MemoryObservationT o;
    o.memory = kMemory;
    fbs::MemorySnapshot snap;
    check(writer_->snapshot(0, 0, address, bytes.data(), bytes.size(), &snap));
    o.snapshots.push_back(snap);
    check(writer_->append(record(std::move(o))));
}

void SceneTrace::submit(uint64_t queue, uint64_t wait_semaphore, uint64_t signal_semaphore, uint64_t fence) {
    fbs::CommandBufferEndT end;
    end.command_buffer = command_buffer_;
    check(writer_->append(record(end)));
    fbs::QueueSubmitT submit;
    submit.queue = queue;
    submit.version = 2;
    auto batch = std::make_unique<fbs::SubmitBatchT>();
    batch->command_buffers.push_back(command_buffer_);
    if (wait_semaphore)
        batch->wait_semaphores.emplace_back(wait_semaphore, 0, VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR, 0);
    if (signal_semaphore) batch->signal_semaphores.emplace_back(signal_semaphore, 0, VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT, 0);
    submit.batches.push_back(std::move(batch));
    submit.fence = fence;
    submit.submission_index = writer_->next_submission_index();
    check(writer_->append(record(std::move(submit))));
    ++command_buffer_;
    fbs::CommandBufferBeginT begin;
    begin.command_buffer = command_buffer_;
    check(writer_->append(record(begin)));
}

void SceneTrace::move_clusters(const std::vector<uint64_t>& cluster_addresses) {
    VkClusterAccelerationStructureMoveObjectsInputNV in{};
    in.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_MOVE_OBJECTS_INPUT_NV;
    in.type = VK_CLUSTER_ACCELERATION_STRUCTURE_TYPE_TRIANGLE_CLUSTER_NV;
    in.noMoveOverlap = VK_TRUE;
    in.maxMovedBytes = 0x8000;
    const auto n = static_cast<uint32_t>(cluster_addresses.size());
    VkClusterAccelerationStructureCommandsInfoNV info{};
    info.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_COMMANDS_INFO_NV;
    info.input.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_INPUT_INFO_NV;
    info.input.maxAccelerationStructureCount = n;
    info.input.opType = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV;
    info.input.opMode = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV;
    info.input.opInput.pMoveObjects = &in;
    info.dstImplicitData = SceneBuffers::kBlasDst;
    info.scratchData = SceneBuffers::kScratch;
    info.dstAddressesArray = {SceneBuffers::kAddresses2, 8, n * 8ull};
    info.dstSizesArray = {SceneBuffers::kSizes2, 4, n * 4ull};
    info.srcInfosArray = {SceneBuffers::kBlasInfos, 8, n * 8ull};
    const uint64_t shift = engine_device_ ? 0 : driver_address_shift;
    std::vector<uint64_t> mirror_sources;
    for (uint64_t a : cluster_addresses) mirror_sources.push_back(a - shift);
    BuildCall call;
    call.capture_outputs = false;
    emit_build(info, call, {{SceneBuffers::kBlasInfos, bytes_of(cluster_addresses.data(), n * 8ull)}}, shift,
               {{SceneBuffers::kBlasInfos, bytes_of(mirror_sources.data(), n * 8ull)}});
}

void SceneTrace::finish() {
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
    check(writer_->finish());
}

}  // namespace clastrace::test
