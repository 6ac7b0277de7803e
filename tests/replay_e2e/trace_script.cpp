// SPDX-License-Identifier: Apache-2.0
#include "trace_script.h"

#include <clastrace/engine/build_sizes.h>
#include <clastrace/trace_building/cluster_records.h>
#include <clastrace/trace_building/command_records.h>
#include <clastrace/trace_building/trace_header.h>

namespace clastrace::test {

namespace tb = trace_building;

namespace {

engine::EngineProperties script_properties(const ScriptDevice& device) {
    engine::EngineProperties p;
    p.max_vertices_per_cluster = device.max_vertices_per_cluster;
    p.max_triangles_per_cluster = device.max_triangles_per_cluster;
    p.cluster_scratch_byte_alignment = device.cluster_scratch_byte_alignment;
    p.cluster_byte_alignment = device.cluster_byte_alignment;
    p.cluster_template_byte_alignment = device.cluster_template_byte_alignment;
    p.cluster_bottom_level_byte_alignment = device.cluster_bottom_level_byte_alignment;
    p.cluster_template_bounds_byte_alignment = device.cluster_template_bounds_byte_alignment;
    p.max_cluster_geometry_index = device.max_cluster_geometry_index;
    return p;
}

fbs::TraceHeaderT script_header(const ScriptDevice& device) {
    const char* driver = device.driver_name ? device.driver_name : tb::kEngineDriver;
    fbs::TraceHeaderT h = tb::trace_header(driver, driver, "replay_e2e_tests (trace_script)");
    h.device->cluster_properties = tb::cluster_properties(script_properties(device));
    return h;
}

std::vector<fbs::MemorySnapshot> snapshots_of(tb::RecordWriter& writer,
                                              const std::vector<InputSnapshot>& list) {
    std::vector<fbs::MemorySnapshot> out;
    for (const InputSnapshot& s : list) out.push_back(writer.snapshot(s.address, s.bytes));
    return out;
}

}  // namespace

TraceScript::TraceScript(const std::string& path, const ScriptDevice& device)
    : writer_(path, script_header(device)), properties_(script_properties(device)) {}

TraceScript::~TraceScript() = default;

void TraceScript::buffer(uint64_t handle, uint64_t address, uint64_t size, uint64_t usage,
                         uint64_t memory, uint64_t memory_offset) {
    writer_.buffer(handle, address, size, usage, memory, memory_offset);
}

void TraceScript::sparse_buffer(uint64_t handle, uint64_t size, uint64_t usage) {
    fbs::BufferCreateT c = tb::buffer_create(handle, size, usage);
    c.create_flags = VK_BUFFER_CREATE_SPARSE_BINDING_BIT;
    writer_.append(std::move(c));
}

void TraceScript::bind_sparse(uint64_t queue, uint64_t buffer, uint64_t address,
                              const std::vector<VkSparseMemoryBind>& binds, uint64_t signal) {
    std::vector<uint64_t> signals;
    if (signal) signals.push_back(signal);
    writer_.append(tb::queue_bind_sparse(queue, buffer, address, binds, {}, signals, 0));
}

void TraceScript::query_build_sizes(const VkClusterAccelerationStructureInputInfoNV& input) {
    const engine::BuildSizes answer = engine::cluster_build_sizes(input, properties_);
    query_build_sizes(input, answer.acceleration_structure_size, answer.build_scratch_size);
}

void TraceScript::query_build_sizes(const VkClusterAccelerationStructureInputInfoNV& input,
                                    uint64_t acceleration_structure_size,
                                    uint64_t build_scratch_size) {
    fbs::GetClusterBuildSizesT q;
    q.input = tb::cluster_input(input);
    q.acceleration_structure_size = acceleration_structure_size;
    q.build_scratch_size = build_scratch_size;
    writer_.append(std::move(q));
}

void TraceScript::acceleration_structure(uint64_t handle, uint64_t buffer, uint64_t offset,
                                         uint64_t size, VkAccelerationStructureTypeKHR type) {
    fbs::AccelerationStructureCreateT c;
    c.acceleration_structure = handle;
    c.api = 1;
    c.type = type;
    c.buffer = buffer;
    c.offset = offset;
    c.size = size;
    writer_.append(std::move(c));
}

void TraceScript::deserialize(uint64_t src_address, uint64_t dst_object,
                              const std::vector<uint8_t>& serialized) {
    ensure_begun();
    fbs::CmdCopyMemoryToAccelerationStructureT c;
    c.command_buffer = command_buffer_;
    c.src_address = src_address;
    c.dst = dst_object;
    c.mode = VK_COPY_ACCELERATION_STRUCTURE_MODE_DESERIALIZE_KHR;
    c.inputs.push_back(writer_.snapshot(src_address, serialized));
    writer_.append(std::move(c));
}

void TraceScript::host_write(uint64_t address, const std::vector<uint8_t>& bytes) {
    fbs::MemoryObservationT o;
    o.memory = 0x1001;
    o.snapshots.push_back(writer_.snapshot(address, bytes));
    writer_.append(std::move(o));
}

void TraceScript::begin(uint64_t command_buffer, uint32_t flags) {
    command_buffer_ = command_buffer;
    writer_.append(tb::command_buffer_begin(command_buffer, flags));
    begun_ = true;
    recorded_ = false;
    commands_ = 0;
}

void TraceScript::begin(uint64_t command_buffer, uint32_t flags, uint32_t level,
                        uint32_t restatement) {
    command_buffer_ = command_buffer;
    fbs::CommandBufferBeginT begin;
    begin.command_buffer = command_buffer;
    begin.flags = flags;
    begin.level = level;
    begin.restatement = restatement;
    writer_.append(begin);
    begun_ = true;
    recorded_ = false;
    commands_ = 0;
}

void TraceScript::end() {
    fbs::CommandBufferEndT end;
    end.command_buffer = command_buffer_;
    writer_.append(end);
    command_buffer_ = next_command_buffer_++;
    begun_ = false;
    recorded_ = false;
}

void TraceScript::execute_commands(const std::vector<uint64_t>& secondaries) {
    ensure_begun();
    fbs::CmdExecuteCommandsT e;
    e.command_buffer = command_buffer_;
    e.secondaries = secondaries;
    writer_.append(std::move(e));
}

void TraceScript::submit_listed(uint64_t queue, const std::vector<uint64_t>& command_buffers,
                                uint64_t fence) {
    fbs::QueueSubmitT s;
    s.queue = queue;
    s.version = 2;
    auto batch = std::make_unique<fbs::SubmitBatchT>();
    batch->command_buffers = command_buffers;
    s.batches.push_back(std::move(batch));
    s.fence = fence;
    s.submission_index = writer_.next_submission_index();
    writer_.append(std::move(s));
}

void TraceScript::ensure_begun() {
    if (!begun_) begin(command_buffer_);
    recorded_ = true;
    ++commands_;
}

void TraceScript::cluster(const VkClusterAccelerationStructureCommandsInfoNV& info,
                          const std::vector<InputSnapshot>& inputs,
                          const std::vector<fbs::DeviceAddressRange>& driver_bvh) {
    ensure_begun();
    fbs::CmdBuildClusterAccelerationStructureIndirectT b = tb::cluster_build(command_buffer_, info);
    b.inputs = snapshots_of(writer_, inputs);
    b.driver_bvh = driver_bvh;
    writer_.append(std::move(b));
}

void TraceScript::copy(uint64_t src_buffer, uint64_t src_offset, uint64_t dst_buffer,
                       uint64_t dst_offset, uint64_t size,
                       const std::vector<InputSnapshot>& inputs) {
    ensure_begun();
    fbs::CmdCopyBufferT c;
    c.command_buffer = command_buffer_;
    c.version = 1;
    c.src_buffer = src_buffer;
    c.dst_buffer = dst_buffer;
    c.regions.emplace_back(src_offset, dst_offset, size);
    c.inputs = snapshots_of(writer_, inputs);
    writer_.append(std::move(c));
}

void TraceScript::command(const fbs::RecordT& record) {
    ensure_begun();
    writer_.append(record);
}

void TraceScript::fill(uint64_t dst_buffer, uint64_t offset, uint64_t size, uint32_t data) {
    ensure_begun();
    fbs::CmdFillBufferT f;
    f.command_buffer = command_buffer_;
    f.dst_buffer = dst_buffer;
    f.dst_offset = offset;
    f.size = size;
    f.data = data;
    writer_.append(f);
}

void TraceScript::update(uint64_t dst_buffer, uint64_t offset, const std::vector<uint8_t>& data) {
    ensure_begun();
    fbs::CmdUpdateBufferT u;
    u.command_buffer = command_buffer_;
    u.dst_buffer = dst_buffer;
    u.dst_offset = offset;
    u.data = data;
    writer_.append(std::move(u));
}

void TraceScript::dispatch(uint64_t storage_buffer, uint64_t offset, uint64_t range,
                           const std::vector<InputSnapshot>& outputs) {
    ensure_begun();
    fbs::CmdDispatchT d;
    d.command_buffer = command_buffer_;
    d.pipeline = 0x7001;
    d.group_count_x = d.group_count_y = d.group_count_z = 1;
    d.storage_buffers.emplace_back(0, 0, 0, VK_DESCRIPTOR_TYPE_STORAGE_BUFFER, storage_buffer,
                                   offset, range, 0);
    d.outputs = snapshots_of(writer_, outputs);
    writer_.append(std::move(d));
}

void TraceScript::dispatch_through_addresses(const std::vector<InputSnapshot>& outputs) {
    ensure_begun();
    fbs::CmdDispatchT d;
    d.command_buffer = command_buffer_;
    d.pipeline = 0x7002;
    d.group_count_x = d.group_count_y = d.group_count_z = 1;
    d.may_write_device_addresses = true;
    d.outputs = snapshots_of(writer_, outputs);
    writer_.append(std::move(d));
}

void TraceScript::exact_address_writes(const std::vector<InputSnapshot>& writes) {
    fbs::DeviceAddressWritesT w;
    w.command_buffer = command_buffer_;
    w.command_index = commands_ - 1;
    w.writes = snapshots_of(writer_, writes);
    for (const InputSnapshot& s : writes) w.compared_bytes += s.bytes.size();
    exact_writes_.push_back(std::move(w));
}

void TraceScript::draw_through_addresses(const std::string& entry_point, uint64_t stages) {
    ensure_begun();
    fbs::CmdDrawT d;
    d.command_buffer = command_buffer_;
    d.pipeline = 0x7003;
    d.entry_point = entry_point;
    d.address_stages = stages;
    writer_.append(std::move(d));
}

void TraceScript::barrier(uint64_t src_stages, uint64_t src_access, uint64_t dst_stages,
                          uint64_t dst_access) {
    ensure_begun();
    writer_.append(
        tb::memory_barrier(command_buffer_, src_stages, src_access, dst_stages, dst_access));
}

void TraceScript::barrier_v1(uint32_t src_stages, uint32_t src_access, uint32_t dst_stages,
                             uint32_t dst_access) {
    ensure_begun();
    writer_.append(
        tb::memory_barrier_v1(command_buffer_, src_stages, src_access, dst_stages, dst_access));
}

void TraceScript::buffer_barrier(uint64_t buffer, uint64_t offset, uint64_t size,
                                 uint64_t src_stages, uint64_t src_access, uint64_t dst_stages,
                                 uint64_t dst_access) {
    ensure_begun();
    fbs::CmdPipelineBarrierT b;
    b.command_buffer = command_buffer_;
    b.version = 2;
    b.dependency = std::make_unique<fbs::DependencyT>();
    b.dependency->buffer_barriers.emplace_back(src_stages, src_access, dst_stages, dst_access,
                                               VK_QUEUE_FAMILY_IGNORED, VK_QUEUE_FAMILY_IGNORED,
                                               buffer, offset, size);
    writer_.append(std::move(b));
}

void TraceScript::set_event(uint64_t event, uint64_t src_stages, uint64_t src_access,
                            uint64_t dst_stages, uint64_t dst_access) {
    ensure_begun();
    writer_.append(
        tb::set_event(command_buffer_, event, src_stages, src_access, dst_stages, dst_access));
}

void TraceScript::wait_event(uint64_t event, uint64_t src_stages, uint64_t src_access,
                             uint64_t dst_stages, uint64_t dst_access) {
    ensure_begun();
    writer_.append(
        tb::wait_event(command_buffer_, event, src_stages, src_access, dst_stages, dst_access));
}

void TraceScript::full_barrier() {
    barrier(VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT, VK_ACCESS_2_MEMORY_WRITE_BIT,
            VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT,
            VK_ACCESS_2_MEMORY_READ_BIT | VK_ACCESS_2_MEMORY_WRITE_BIT);
}

void TraceScript::next_command_buffer() {
    ensure_begun();
    writer_.append(tb::command_buffer_end(command_buffer_));
    batch_.push_back(command_buffer_);
    command_buffer_ = next_command_buffer_++;
    begun_ = false;
    recorded_ = false;
}

void TraceScript::submit(uint64_t queue, const std::vector<SemaphoreUse>& waits,
                         const std::vector<SemaphoreUse>& signals, uint64_t fence,
                         uint8_t version) {
    ensure_begun();
    writer_.append(tb::command_buffer_end(command_buffer_));
    std::vector<uint64_t> command_buffers = std::move(batch_);
    batch_.clear();
    command_buffers.push_back(command_buffer_);
    for (fbs::DeviceAddressWritesT& w : exact_writes_) {
        w.submission = writer_.next_submission_index();
        writer_.append(std::move(w));
    }
    exact_writes_.clear();
    fbs::QueueSubmitT s =
        tb::queue_submit(queue, std::move(command_buffers), fence, writer_.next_submission_index());
    s.version = version;
    fbs::SubmitBatchT& batch = *s.batches[0];
    for (const SemaphoreUse& w : waits)
        batch.wait_semaphores.emplace_back(w.semaphore, w.value, w.stages, 0);
    // vkQueueSubmit has no signal stage mask (the capture records ALL_COMMANDS); a v1 record
    // with another mask tests that replay ignores it.
    for (const SemaphoreUse& g : signals)
        batch.signal_semaphores.emplace_back(g.semaphore, g.value, g.stages, 0);
    writer_.append(std::move(s));
    command_buffer_ = next_command_buffer_++;
    begun_ = false;
    recorded_ = false;
}

void TraceScript::resubmit(uint64_t queue, uint64_t command_buffer, uint64_t fence) {
    writer_.append(
        tb::queue_submit(queue, {command_buffer}, fence, writer_.next_submission_index()));
}

void TraceScript::wait_fence(uint64_t fence) { writer_.wait_fence(fence); }

void TraceScript::device_wait_idle() { writer_.append(fbs::DeviceWaitIdleT{}); }

void TraceScript::present(uint64_t queue, const std::vector<uint64_t>& waits, uint64_t frame) {
    fbs::QueuePresentT p;
    p.queue = queue;
    p.frame = frame;
    p.wait_semaphores = waits;
    p.swapchains = {0x5c};
    p.image_indices = {0};
    writer_.append(std::move(p));
}

void TraceScript::acquire(uint64_t semaphore, uint64_t fence, int32_t result,
                          uint32_t device_mask) {
    fbs::AcquireNextImageT a;
    a.swapchain = 0x5c;
    a.timeout = ~0ull;
    a.semaphore = semaphore;
    a.fence = fence;
    a.result = result;
    a.device_mask = device_mask;
    writer_.append(std::move(a));
}

void TraceScript::reset(uint64_t command_buffer, uint64_t pool) {
    fbs::CommandBufferResetT r;
    r.command_buffer = command_buffer;
    r.command_pool = pool;
    writer_.append(r);
}

void TraceScript::finish() {
    if (recorded_) submit(0x9001, {}, {}, 0xfe1);
    device_wait_idle();
    writer_.finish();
}

}  // namespace clastrace::test
