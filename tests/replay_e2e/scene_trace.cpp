// SPDX-License-Identifier: Apache-2.0
#include "scene_trace.h"

#include <clastrace/common/enum_bits.h>
#include <clastrace/trace_building/cluster_records.h>
#include <clastrace/trace_building/cluster_structs.h>
#include <clastrace/trace_building/command_records.h>
#include <clastrace/trace_building/trace_header.h>

#include <cstring>

namespace clastrace::test {

namespace tb = trace_building;

namespace {
constexpr uint64_t kFirstCommandBuffer = 0xc0de, kQueue = 0x9001, kFence = 0xfe1, kMemory = 0x1001,
                   kHostMemory = 0x1002;
constexpr uint64_t kStaging = 0x2100;
constexpr uint32_t kClusters = 2, kGrid = 3, kVerts = kGrid * kGrid,
                   kTris = (kGrid - 1) * (kGrid - 1) * 2;

fbs::TraceHeaderT scene_header(bool engine_device) {
    fbs::TraceHeaderT h =
        tb::trace_header(engine_device ? tb::kEngineDriver : "test driver",
                         engine_device ? tb::kEngineDriver : "NVIDIA", "replay_e2e_tests");
    h.device->cluster_properties =
        tb::cluster_properties(engine::EngineProperties::nvidia_default());
    return h;
}
}  // namespace

SceneTrace::~SceneTrace() = default;

void SceneTrace::add_buffer(uint64_t handle, uint64_t address, uint64_t size, uint64_t usage,
                            uint64_t memory, uint64_t offset) {
    writer_.buffer(handle, address, size, usage, memory, offset);
    if (address) mirror_.add_buffer(address, size, usage);
}

SceneTrace::SceneTrace(const std::string& path, bool engine_device, uint64_t scratch_size)
    : writer_(path, scene_header(engine_device)),
      scratch_size_(scratch_size),
      engine_device_(engine_device),
      command_buffer_(kFirstCommandBuffer) {
    const uint64_t sda = VK_BUFFER_USAGE_SHADER_DEVICE_ADDRESS_BIT;
    const uint64_t input =
        sda | VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_BIT_KHR;
    const uint64_t as_storage = sda | VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_STORAGE_BIT_KHR |
                                VK_BUFFER_USAGE_STORAGE_BUFFER_BIT;
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
            uint8_t a = uint8_t(y * kGrid + x), b = uint8_t(a + 1), c = uint8_t(a + kGrid),
                    d = uint8_t(c + 1);
            for (uint8_t v : {a, b, c, b, d, c}) indices_.push_back(v);
        }
    for (uint32_t c = 0; c < kClusters; ++c)
        infos.push_back(tb::triangle_cluster_info(100 + c, kTris, kVerts, B::kIndices, 1,
                                                  B::kVertices + c * kVerts * 12));
    writer_.append(tb::command_buffer_begin(command_buffer_));
}

void SceneTrace::copy_infos() {
    fbs::CmdCopyBufferT copy;
    copy.command_buffer = command_buffer_;
    copy.version = 1;
    copy.src_buffer = kStaging;
    copy.dst_buffer = 0x2003;
    const uint64_t n = infos.size() * sizeof infos[0];
    copy.regions.emplace_back(0, 0, n);
    copy.inputs.push_back(writer_.snapshot(0, infos.data(), n, kStaging));
    writer_.append(std::move(copy));
}

void SceneTrace::barrier(uint64_t src_stage, uint64_t src_access, uint64_t dst_stage,
                         uint64_t dst_access) {
    writer_.append(
        tb::memory_barrier(command_buffer_, src_stage, src_access, dst_stage, dst_access));
}

void SceneTrace::barrier_v1(uint32_t src_stage, uint32_t src_access, uint32_t dst_stage,
                            uint32_t dst_access) {
    fbs::CmdPipelineBarrierT b =
        tb::memory_barrier(command_buffer_, src_stage, src_access, dst_stage, dst_access);
    b.version = 1;
    b.src_stage_mask = src_stage;
    b.dst_stage_mask = dst_stage;
    writer_.append(std::move(b));
}

void SceneTrace::set_event(uint64_t event, uint64_t src_stage, uint64_t src_access,
                           uint64_t dst_stage, uint64_t dst_access) {
    writer_.append(
        tb::set_event(command_buffer_, event, src_stage, src_access, dst_stage, dst_access));
}

void SceneTrace::wait_event(uint64_t event, uint64_t src_stage, uint64_t src_access,
                            uint64_t dst_stage, uint64_t dst_access) {
    writer_.append(
        tb::wait_event(command_buffer_, event, src_stage, src_access, dst_stage, dst_access));
}

void SceneTrace::emit_build(
    const VkClusterAccelerationStructureCommandsInfoNV& info, const BuildCall& call,
    std::vector<std::pair<uint64_t, std::vector<uint8_t>>> inputs, uint64_t shift,
    const std::vector<std::pair<uint64_t, std::vector<uint8_t>>>& mirror_patch) {
    for (const auto& list : {inputs, mirror_patch})
        for (const auto& [address, bytes] : list) mirror_.write(address, bytes);
    const engine::ExecutionRecord r = mirror_.execute(info);

    fbs::CmdBuildClusterAccelerationStructureIndirectT b = tb::cluster_build(command_buffer_, info);
    for (auto& [address, bytes] : inputs) b.inputs.push_back(writer_.snapshot(address, bytes));
    if (call.capture_outputs) {
        const uint64_t n = info.input.maxAccelerationStructureCount;
        std::vector<uint64_t> addresses(n);
        for (uint64_t i = 0; i < n && i < r.ops.size(); ++i)
            addresses[i] = r.ops[i].dst_address ? r.ops[i].dst_address + shift : 0;
        b.outputs.push_back(
            writer_.snapshot(info.dstAddressesArray.deviceAddress, addresses.data(), n * 8));
        b.outputs.push_back(
            writer_.snapshot(info.dstSizesArray.deviceAddress,
                             mirror_.read(info.dstSizesArray.deviceAddress, n * 4)));
        if (engine_device_ && r.implicit_bytes_used) {
            std::vector<uint8_t> objects =
                mirror_.read(info.dstImplicitData, r.implicit_bytes_used);
            if (call.corrupt_output_byte)
                objects[call.corrupt_output_byte % objects.size()] ^= 0x40;
            b.outputs.push_back(writer_.snapshot(info.dstImplicitData, objects));
        }
    }
    writer_.append(std::move(b));
}

void SceneTrace::build(const BuildCall& call) {
    auto tri = tb::triangle_cluster_limits(kTris, kVerts, kTris * kClusters, kVerts * kClusters);
    common::set_enum_bits(tri.vertexFormat, call.vertex_format);
    auto info =
        tb::cluster_commands(tb::cluster_op_input(static_cast<uint32_t>(infos.size()), &tri));
    common::set_enum_bits(info.input.opType, call.op_type);
    info.dstImplicitData = call.dst;
    info.scratchData = call.scratch;
    info.dstAddressesArray = {call.addresses, 8, infos.size() * 8};
    info.dstSizesArray = {call.sizes, 4, infos.size() * 4};
    info.srcInfosArray = {SceneBuffers::kInfos, sizeof infos[0], infos.size() * sizeof infos[0]};
    std::vector<VkClusterAccelerationStructureBuildTriangleClusterInfoNV> call_infos = infos;
    for (size_t c = 0; c < call_infos.size(); ++c)
        if (call_infos[c].clusterID != 0xFFFFFFFFu)
            call_infos[c].clusterID = call.first_cluster_id + uint32_t(c);
    emit_build(info, call,
               {{SceneBuffers::kInfos, tb::bytes_of(call_infos)},
                {SceneBuffers::kIndices, indices_},
                {SceneBuffers::kVertices, tb::bytes_of(vertices_)}},
               engine_device_ ? 0 : driver_address_shift);
}

void SceneTrace::build_blas(const std::vector<uint64_t>& cluster_addresses) {
    VkClusterAccelerationStructureClustersBottomLevelInputNV in{};
    in.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_CLUSTERS_BOTTOM_LEVEL_INPUT_NV;
    in.maxTotalClusterCount = static_cast<uint32_t>(cluster_addresses.size());
    in.maxClusterCountPerAccelerationStructure = in.maxTotalClusterCount;
    auto info = tb::cluster_commands(tb::cluster_op_input(1, &in));
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
               {{blas.clusterReferences, tb::bytes_of(mirror_refs)}});
}

void SceneTrace::wait_fence(uint64_t fence) { writer_.wait_fence(fence); }

void SceneTrace::observe(uint64_t address, const std::vector<uint8_t>& bytes, uint32_t reason) {
    fbs::MemoryObservationT o;
    o.memory = kMemory;
    o.reason = reason;
    o.snapshots.push_back(writer_.snapshot(address, bytes));
    writer_.append(std::move(o));
}

void SceneTrace::submit(uint64_t queue, uint64_t wait_semaphore, uint64_t signal_semaphore,
                        uint64_t fence) {
    writer_.append(tb::command_buffer_end(command_buffer_));
    fbs::QueueSubmitT submit =
        tb::queue_submit(queue, {command_buffer_}, fence, writer_.next_submission_index());
    fbs::SubmitBatchT& batch = *submit.batches[0];
    if (wait_semaphore)
        batch.wait_semaphores.emplace_back(wait_semaphore, 0,
                                           VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                                           0);
    if (signal_semaphore)
        batch.signal_semaphores.emplace_back(signal_semaphore, 0,
                                             VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT, 0);
    writer_.append(std::move(submit));
    ++command_buffer_;
    writer_.append(tb::command_buffer_begin(command_buffer_));
}

void SceneTrace::move_clusters(const std::vector<uint64_t>& cluster_addresses) {
    VkClusterAccelerationStructureMoveObjectsInputNV in{};
    in.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_MOVE_OBJECTS_INPUT_NV;
    in.type = VK_CLUSTER_ACCELERATION_STRUCTURE_TYPE_TRIANGLE_CLUSTER_NV;
    in.noMoveOverlap = VK_TRUE;
    in.maxMovedBytes = 0x8000;
    const auto n = static_cast<uint32_t>(cluster_addresses.size());
    auto info = tb::cluster_commands(tb::cluster_op_input(n, &in));
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
    emit_build(info, call, {{SceneBuffers::kBlasInfos, tb::bytes_of(cluster_addresses)}}, shift,
               {{SceneBuffers::kBlasInfos, tb::bytes_of(mirror_sources)}});
}

void SceneTrace::finish() {
    writer_.end_and_submit(kQueue, command_buffer_, kFence);
    writer_.wait_fence(kFence);
    writer_.finish();
}

}  // namespace clastrace::test
