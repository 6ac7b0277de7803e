#include "trace_script.h"

#include <stdexcept>

namespace clastrace::test {

namespace {

template <class T>
fbs::RecordT record(T body) {
    fbs::RecordT r;
    r.body.Set(std::move(body));
    return r;
}

void check(const traces::TraceError& e) {
    if (e) throw std::runtime_error(e.message);
}

std::unique_ptr<fbs::ClusterInputInfoT> input_of(const VkClusterAccelerationStructureInputInfoNV& in) {
    auto out = std::make_unique<fbs::ClusterInputInfoT>();
    out->max_acceleration_structure_count = in.maxAccelerationStructureCount;
    out->flags = in.flags;
    out->op_type = in.opType;
    out->op_mode = in.opMode;
    if (in.opType == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV) {
        fbs::ClustersBottomLevelInputT b;
        b.max_total_cluster_count = in.opInput.pClustersBottomLevel->maxTotalClusterCount;
        b.max_cluster_count_per_acceleration_structure = in.opInput.pClustersBottomLevel->maxClusterCountPerAccelerationStructure;
        out->op_input.Set(std::move(b));
    } else if (in.opType == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV) {
        fbs::MoveObjectsInputT m;
        m.type = in.opInput.pMoveObjects->type;
        m.no_move_overlap = in.opInput.pMoveObjects->noMoveOverlap;
        m.max_moved_bytes = in.opInput.pMoveObjects->maxMovedBytes;
        out->op_input.Set(std::move(m));
    } else if (in.opInput.pTriangleClusters) {
        const auto& t = *in.opInput.pTriangleClusters;
        fbs::TriangleClusterInputT c;
        c.vertex_format = t.vertexFormat;
        c.max_geometry_index_value = t.maxGeometryIndexValue;
        c.max_cluster_unique_geometry_count = t.maxClusterUniqueGeometryCount;
        c.max_cluster_triangle_count = t.maxClusterTriangleCount;
        c.max_cluster_vertex_count = t.maxClusterVertexCount;
        c.max_total_triangle_count = t.maxTotalTriangleCount;
        c.max_total_vertex_count = t.maxTotalVertexCount;
        c.min_position_truncate_bit_count = t.minPositionTruncateBitCount;
        out->op_input.Set(std::move(c));
    }
    return out;
}

std::unique_ptr<fbs::StridedDeviceAddressRegion> region_of(const VkStridedDeviceAddressRegionKHR& r) {
    return std::make_unique<fbs::StridedDeviceAddressRegion>(r.deviceAddress, r.stride, r.size);
}

}  // namespace

TraceScript::TraceScript(const std::string& path, const ScriptDevice& device) {
    fbs::TraceHeaderT h;
    h.device = std::make_unique<fbs::DeviceInfoT>();
    h.device->name = "clastrace engine";
    h.device->driver_name = "clastrace engine";
    h.device->cluster_properties = std::make_unique<fbs::ClusterPropertiesT>();
    auto& p = *h.device->cluster_properties;
    p.max_vertices_per_cluster = device.max_vertices_per_cluster;
    p.max_triangles_per_cluster = device.max_triangles_per_cluster;
    p.cluster_scratch_byte_alignment = device.cluster_scratch_byte_alignment;
    p.cluster_byte_alignment = device.cluster_byte_alignment;
    p.cluster_template_byte_alignment = device.cluster_template_byte_alignment;
    p.cluster_bottom_level_byte_alignment = device.cluster_bottom_level_byte_alignment;
    p.cluster_template_bounds_byte_alignment = device.cluster_template_bounds_byte_alignment;
    p.max_cluster_geometry_index = device.max_cluster_geometry_index;
    h.capture = std::make_unique<fbs::CaptureSettingsT>();
    h.capture->capture_tool = "replay_e2e_tests (trace_script)";
    traces::TraceError e;
    traces::TraceWriterOptions o;
    o.sync_on_finish = false;
    writer_ = traces::TraceWriter::create(path, h, o, &e);
    check(e);
}

TraceScript::~TraceScript() = default;

void TraceScript::buffer(uint64_t handle, uint64_t address, uint64_t size, uint64_t usage, uint64_t memory,
                         uint64_t memory_offset) {
    fbs::BufferCreateT c;
    c.buffer = handle;
    c.size = size;
    c.usage = usage;
    check(writer_->append(record(c)));
    fbs::BufferBindMemoryT b;
    b.buffer = handle;
    b.memory = memory;
    b.memory_offset = memory_offset;
    b.device_address = address;
    check(writer_->append(record(b)));
}

void TraceScript::query_build_sizes(const VkClusterAccelerationStructureInputInfoNV& input) {
    fbs::GetClusterBuildSizesT q;
    q.input = input_of(input);
    check(writer_->append(record(std::move(q))));
}

void TraceScript::acceleration_structure(uint64_t handle, uint64_t buffer, uint64_t offset, uint64_t size) {
    fbs::AccelerationStructureCreateT c;
    c.acceleration_structure = handle;
    c.api = 1;
    c.type = VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR;
    c.buffer = buffer;
    c.offset = offset;
    c.size = size;
    check(writer_->append(record(std::move(c))));
}

void TraceScript::deserialize(uint64_t src_address, uint64_t dst_object, const std::vector<uint8_t>& serialized) {
    ensure_begun();
    fbs::CmdCopyMemoryToAccelerationStructureT c;
    c.command_buffer = command_buffer_;
    c.src_address = src_address;
    c.dst = dst_object;
    c.mode = VK_COPY_ACCELERATION_STRUCTURE_MODE_DESERIALIZE_KHR;
    fbs::MemorySnapshot snap;
    check(writer_->snapshot(0, 0, src_address, serialized.data(), serialized.size(), &snap));
    c.inputs.push_back(snap);
    check(writer_->append(record(std::move(c))));
}

void TraceScript::host_write(uint64_t address, const std::vector<uint8_t>& bytes) {
    fbs::MemoryObservationT o;
    o.memory = 0x1001;
    fbs::MemorySnapshot snap;
    check(writer_->snapshot(0, 0, address, bytes.data(), bytes.size(), &snap));
    o.snapshots.push_back(snap);
    check(writer_->append(record(std::move(o))));
}

void TraceScript::begin(uint64_t command_buffer, uint32_t flags) {
    command_buffer_ = command_buffer;
    fbs::CommandBufferBeginT begin;
    begin.command_buffer = command_buffer;
    begin.flags = flags;
    check(writer_->append(record(begin)));
    begun_ = true;
    recorded_ = false;
    commands_ = 0;
}

void TraceScript::begin(uint64_t command_buffer, uint32_t flags, uint32_t level, uint32_t restatement) {
    command_buffer_ = command_buffer;
    fbs::CommandBufferBeginT begin;
    begin.command_buffer = command_buffer;
    begin.flags = flags;
    begin.level = level;
    begin.restatement = restatement;
    check(writer_->append(record(begin)));
    begun_ = true;
    recorded_ = false;
    commands_ = 0;
}

void TraceScript::end() {
    fbs::CommandBufferEndT end;
    end.command_buffer = command_buffer_;
    check(writer_->append(record(end)));
    command_buffer_ = next_command_buffer_++;
    begun_ = false;
    recorded_ = false;
}

void TraceScript::execute_commands(const std::vector<uint64_t>& secondaries) {
    ensure_begun();
    fbs::CmdExecuteCommandsT e;
    e.command_buffer = command_buffer_;
    e.secondaries = secondaries;
    check(writer_->append(record(std::move(e))));
}

void TraceScript::submit_listed(uint64_t queue, const std::vector<uint64_t>& command_buffers, uint64_t fence) {
    fbs::QueueSubmitT s;
    s.queue = queue;
    s.version = 2;
    auto batch = std::make_unique<fbs::SubmitBatchT>();
    batch->command_buffers = command_buffers;
    s.batches.push_back(std::move(batch));
    s.fence = fence;
    s.submission_index = writer_->next_submission_index();
    check(writer_->append(record(std::move(s))));
}

void TraceScript::ensure_begun() {
    if (!begun_) begin(command_buffer_);
    recorded_ = true;
    ++commands_;
}

void TraceScript::cluster(const VkClusterAccelerationStructureCommandsInfoNV& info, const std::vector<InputSnapshot>& inputs) {
    ensure_begun();
    fbs::CmdBuildClusterAccelerationStructureIndirectT b;
    b.command_buffer = command_buffer_;
    b.input = input_of(info.input);
    b.dst_implicit_data = info.dstImplicitData;
    b.scratch_data = info.scratchData;
    b.dst_addresses_array = region_of(info.dstAddressesArray);
    b.dst_sizes_array = region_of(info.dstSizesArray);
    b.src_infos_array = region_of(info.srcInfosArray);
    b.src_infos_count = info.srcInfosCount;
    b.address_resolution_flags = info.addressResolutionFlags;
    for (const InputSnapshot& s : inputs) {
        fbs::MemorySnapshot snap;
        check(writer_->snapshot(0, 0, s.address, s.bytes.data(), s.bytes.size(), &snap));
        b.inputs.push_back(snap);
    }
    check(writer_->append(record(std::move(b))));
}

void TraceScript::copy(uint64_t src_buffer, uint64_t src_offset, uint64_t dst_buffer, uint64_t dst_offset, uint64_t size,
                       const std::vector<InputSnapshot>& inputs) {
    ensure_begun();
    fbs::CmdCopyBufferT c;
    c.command_buffer = command_buffer_;
    c.version = 1;
    c.src_buffer = src_buffer;
    c.dst_buffer = dst_buffer;
    c.regions.emplace_back(src_offset, dst_offset, size);
    for (const InputSnapshot& s : inputs) {
        fbs::MemorySnapshot snap;
        check(writer_->snapshot(0, 0, s.address, s.bytes.data(), s.bytes.size(), &snap));
        c.inputs.push_back(snap);
    }
    check(writer_->append(record(std::move(c))));
}

void TraceScript::fill(uint64_t dst_buffer, uint64_t offset, uint64_t size, uint32_t data) {
    ensure_begun();
    fbs::CmdFillBufferT f;
    f.command_buffer = command_buffer_;
    f.dst_buffer = dst_buffer;
    f.dst_offset = offset;
    f.size = size;
    f.data = data;
    check(writer_->append(record(f)));
}

void TraceScript::update(uint64_t dst_buffer, uint64_t offset, const std::vector<uint8_t>& data) {
    ensure_begun();
    fbs::CmdUpdateBufferT u;
    u.command_buffer = command_buffer_;
    u.dst_buffer = dst_buffer;
    u.dst_offset = offset;
    u.data = data;
    check(writer_->append(record(std::move(u))));
}

void TraceScript::dispatch(uint64_t storage_buffer, uint64_t offset, uint64_t range, const std::vector<InputSnapshot>& outputs) {
    ensure_begun();
    fbs::CmdDispatchT d;
    d.command_buffer = command_buffer_;
    d.pipeline = 0x7001;
    d.group_count_x = d.group_count_y = d.group_count_z = 1;
    d.storage_buffers.emplace_back(0, 0, 0, VK_DESCRIPTOR_TYPE_STORAGE_BUFFER, storage_buffer, offset, range, 0);
    for (const InputSnapshot& s : outputs) {
        fbs::MemorySnapshot snap;
        check(writer_->snapshot(0, 0, s.address, s.bytes.data(), s.bytes.size(), &snap));
        d.outputs.push_back(snap);
    }
    check(writer_->append(record(std::move(d))));
}

void TraceScript::barrier(uint64_t src_stages, uint64_t src_access, uint64_t dst_stages, uint64_t dst_access) {
    ensure_begun();
    fbs::CmdPipelineBarrierT b;
    b.command_buffer = command_buffer_;
    b.version = 2;
    b.dependency = std::make_unique<fbs::DependencyT>();
    b.dependency->memory_barriers.emplace_back(src_stages, src_access, dst_stages, dst_access);
    check(writer_->append(record(std::move(b))));
}

void TraceScript::buffer_barrier(uint64_t buffer, uint64_t offset, uint64_t size, uint64_t src_stages, uint64_t src_access,
                                 uint64_t dst_stages, uint64_t dst_access) {
    ensure_begun();
    fbs::CmdPipelineBarrierT b;
    b.command_buffer = command_buffer_;
    b.version = 2;
    b.dependency = std::make_unique<fbs::DependencyT>();
    b.dependency->buffer_barriers.emplace_back(src_stages, src_access, dst_stages, dst_access, VK_QUEUE_FAMILY_IGNORED,
                                               VK_QUEUE_FAMILY_IGNORED, buffer, offset, size);
    check(writer_->append(record(std::move(b))));
}

void TraceScript::set_event(uint64_t event, uint64_t src_stages, uint64_t src_access, uint64_t dst_stages,
                            uint64_t dst_access) {
    ensure_begun();
    fbs::CmdSetEventT e;
    e.command_buffer = command_buffer_;
    e.event = event;
    e.version = 2;
    e.dependency = std::make_unique<fbs::DependencyT>();
    e.dependency->memory_barriers.emplace_back(src_stages, src_access, dst_stages, dst_access);
    check(writer_->append(record(std::move(e))));
}

void TraceScript::wait_event(uint64_t event, uint64_t src_stages, uint64_t src_access, uint64_t dst_stages,
                             uint64_t dst_access) {
    ensure_begun();
    fbs::CmdWaitEventsT w;
    w.command_buffer = command_buffer_;
    w.version = 2;
    w.events.push_back(event);
    auto dep = std::make_unique<fbs::DependencyT>();
    dep->memory_barriers.emplace_back(src_stages, src_access, dst_stages, dst_access);
    w.dependencies.push_back(std::move(dep));
    check(writer_->append(record(std::move(w))));
}

void TraceScript::full_barrier() {
    barrier(VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT, VK_ACCESS_2_MEMORY_WRITE_BIT, VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT,
            VK_ACCESS_2_MEMORY_READ_BIT | VK_ACCESS_2_MEMORY_WRITE_BIT);
}

void TraceScript::next_command_buffer() {
    ensure_begun();
    fbs::CommandBufferEndT end;
    end.command_buffer = command_buffer_;
    check(writer_->append(record(end)));
    batch_.push_back(command_buffer_);
    command_buffer_ = next_command_buffer_++;
    begun_ = false;
    recorded_ = false;
}

void TraceScript::submit(uint64_t queue, const std::vector<SemaphoreUse>& waits, const std::vector<SemaphoreUse>& signals,
                         uint64_t fence, uint8_t version) {
    ensure_begun();
    fbs::CommandBufferEndT end;
    end.command_buffer = command_buffer_;
    check(writer_->append(record(end)));
    fbs::QueueSubmitT s;
    s.queue = queue;
    s.version = version;
    auto batch = std::make_unique<fbs::SubmitBatchT>();
    batch->command_buffers = std::move(batch_);
    batch_.clear();
    batch->command_buffers.push_back(command_buffer_);
    for (const SemaphoreUse& w : waits) batch->wait_semaphores.emplace_back(w.semaphore, w.value, w.stages, 0);
    // vkQueueSubmit has no signal stage mask (the capture records ALL_COMMANDS); a v1 record
    // with another mask tests that replay ignores it.
    for (const SemaphoreUse& g : signals) batch->signal_semaphores.emplace_back(g.semaphore, g.value, g.stages, 0);
    s.batches.push_back(std::move(batch));
    s.fence = fence;
    s.submission_index = writer_->next_submission_index();
    check(writer_->append(record(std::move(s))));
    command_buffer_ = next_command_buffer_++;
    begun_ = false;
    recorded_ = false;
}

void TraceScript::resubmit(uint64_t queue, uint64_t command_buffer, uint64_t fence) {
    fbs::QueueSubmitT s;
    s.queue = queue;
    s.version = 2;
    auto batch = std::make_unique<fbs::SubmitBatchT>();
    batch->command_buffers.push_back(command_buffer);
    s.batches.push_back(std::move(batch));
    s.fence = fence;
    s.submission_index = writer_->next_submission_index();
    check(writer_->append(record(std::move(s))));
}

void TraceScript::wait_fence(uint64_t fence) {
    fbs::FenceWaitT w;
    w.fences.push_back(fence);
    w.wait_all = true;
    check(writer_->append(record(std::move(w))));
}

void TraceScript::device_wait_idle() { check(writer_->append(record(fbs::DeviceWaitIdleT{}))); }

void TraceScript::reset(uint64_t command_buffer, uint64_t pool) {
    fbs::CommandBufferResetT r;
    r.command_buffer = command_buffer;
    r.command_pool = pool;
    check(writer_->append(record(r)));
}

void TraceScript::finish() {
    if (recorded_) submit(0x9001, {}, {}, 0xfe1);
    device_wait_idle();
    check(writer_->finish());
}

}  // namespace clastrace::test
