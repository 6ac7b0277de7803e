// SPDX-License-Identifier: Apache-2.0
#include "consumer_trace.h"

#include <clastrace/trace_building/command_records.h>
#include <clastrace/trace_building/consumer_records.h>
#include <clastrace/trace_building/trace_header.h>

namespace clastrace::consumertest {
namespace {

namespace tb = trace_building;

constexpr uint64_t kQueue = 0x9001, kBufferMemory = 0x1001, kObjectMemory = 0x1002;
constexpr uint64_t kObjectBytes = 4096;

fbs::TraceHeaderT header() {
    return tb::trace_header("NVIDIA H100 (test double)", "NVIDIA", "replay_consumers_tests");
}

fbs::AccelerationStructureInfoNVT info_of(VkAccelerationStructureTypeNV type, uint32_t instances) {
    fbs::AccelerationStructureInfoNVT info;
    info.type = type;
    info.instance_count = instances;
    return info;
}

}  // namespace

ConsumerTrace::ConsumerTrace(const std::string& path) : writer_(path, header()) {}

uint64_t ConsumerTrace::buffer(const void* bytes, uint64_t size) {
    const uint64_t handle = next_buffer_++, address = next_address_;
    last_address_ = address;
    next_address_ += (size + 0xFFFF) / 0x10000 * 0x10000;
    writer_.buffer(handle, address, size,
                   VK_BUFFER_USAGE_RAY_TRACING_BIT_NV | VK_BUFFER_USAGE_SHADER_DEVICE_ADDRESS_BIT,
                   kBufferMemory, address - 0x10000000);
    if (bytes) inputs_.push_back(writer_.snapshot(address, bytes, size, handle));
    return handle;
}

uint64_t ConsumerTrace::open() {
    if (secondary_) return secondary_;
    if (!open_) writer_.append(tb::command_buffer_begin(command_buffer_));
    open_ = true;
    return command_buffer_;
}

// vkCreateAccelerationStructureNV, its object requirement and its bind to object memory.
ConsumerTrace::Object ConsumerTrace::create_nv(const fbs::AccelerationStructureInfoNVT& info) {
    Object o{next_object_++, 0};
    o.driver_handle = 0x7F00'0000'0000ull + o.handle * 0x1000;
    fbs::AccelerationStructureCreateT c;
    c.acceleration_structure = o.handle;
    c.api = 0;
    c.type = info.type;
    c.info = std::make_unique<fbs::AccelerationStructureInfoNVT>(info);
    c.device_address = o.driver_handle;
    writer_.append(std::move(c));
    fbs::AccelerationStructureMemoryRequirementsNVT q;
    q.acceleration_structure = o.handle;
    q.type = VK_ACCELERATION_STRUCTURE_MEMORY_REQUIREMENTS_TYPE_OBJECT_NV;
    q.size = kObjectBytes;
    q.alignment = 256;
    writer_.append(q);
    fbs::AccelerationStructureBindMemoryT b;
    b.acceleration_structure = o.handle;
    b.memory = kObjectMemory;
    b.memory_offset = next_object_offset_;
    next_object_offset_ += 0x10000;
    writer_.append(b);
    return o;
}

ConsumerTrace::Object ConsumerTrace::bottom_level() {
    fbs::AccelerationStructureInfoNVT info =
        info_of(VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_NV, 0);
    auto geo = std::make_unique<fbs::GeometryNVT>();
    geo->geometry_type = VK_GEOMETRY_TYPE_TRIANGLES_NV;
    geo->triangles =
        std::make_unique<fbs::GeometryTrianglesNV>(0, 0, 3, uint32_t(VK_FORMAT_R32G32B32_SFLOAT),
                                                   12, 0, 0, 3, uint32_t(VK_INDEX_TYPE_UINT32), 0,
                                                   0);
    geo->aabbs = std::make_unique<fbs::GeometryAabbNV>();
    info.geometries.push_back(std::move(geo));
    return create_nv(info);
}

ConsumerTrace::Object ConsumerTrace::top_level(uint32_t instances) {
    return create_nv(info_of(VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_NV, instances));
}

ConsumerTrace::Object ConsumerTrace::khr_structure(bool top_level, uint64_t* buffer_out) {
    const uint64_t b = buffer(nullptr, kObjectBytes);
    if (buffer_out) *buffer_out = b;
    const uint64_t address = last_address_;
    Object o{next_object_++, address};
    fbs::AccelerationStructureCreateT c;
    c.acceleration_structure = o.handle;
    c.api = 1;
    c.type = top_level ? VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_KHR
                       : VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR;
    c.buffer = b;
    c.size = kObjectBytes;
    c.device_address = address;
    writer_.append(std::move(c));
    return o;
}

void ConsumerTrace::build_khr_top(const Object& tlas, const std::vector<Object>& blas,
                                  bool array_of_pointers) {
    std::vector<uint64_t> references;
    for (const Object& o : blas) references.push_back(o.driver_handle);
    const std::vector<uint8_t> instances = tb::packed_instances(references);
    buffer(instances.data(), instances.size());
    uint64_t data = last_address_;
    if (array_of_pointers) {
        std::vector<uint64_t> pointers;  // the instances in reverse order, to tell them apart
        for (size_t i = blas.size(); i-- > 0;) pointers.push_back(data + i * 64);
        buffer(pointers.data(), pointers.size() * 8);
        data = last_address_;
    }
    const uint64_t scratch = buffer(nullptr, 1 << 16);
    fbs::CmdBuildAccelerationStructuresKHRT b;
    b.command_buffer = open();
    auto info = std::make_unique<fbs::AccelerationStructureBuildInfoKHRT>();
    info->type = VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_KHR;
    info->dst = tlas.handle;
    auto geometry = std::make_unique<fbs::GeometryKHRT>();
    geometry->geometry_type = VK_GEOMETRY_TYPE_INSTANCES_KHR;
    geometry->instances = std::make_unique<fbs::GeometryInstancesKHR>(array_of_pointers, data);
    info->geometries.push_back(std::move(geometry));
    info->scratch_address = scratch ? last_address_ : 0;
    info->ranges.emplace_back(uint32_t(blas.size()), 0, 0, 0);
    b.infos.push_back(std::move(info));
    b.inputs = std::move(inputs_);
    inputs_.clear();
    writer_.append(std::move(b));
}

void ConsumerTrace::fill(uint64_t buffer) {
    fbs::CmdFillBufferT f;
    f.command_buffer = open();
    f.dst_buffer = buffer;
    f.size = VK_WHOLE_SIZE;
    f.data = 0xDEADBEEF;
    writer_.append(f);
}

void ConsumerTrace::build_bottom(const Object& blas) {
    const float vertices[9] = {0, 0, 1, 1, 0, 1, 0, 1, 1};
    const uint32_t indices[3] = {0, 1, 2};
    const uint64_t v = buffer(vertices, sizeof vertices), i = buffer(indices, sizeof indices);
    const uint64_t scratch = buffer(nullptr, 1 << 16);
    fbs::CmdBuildAccelerationStructureNVT b;
    b.command_buffer = open();
    b.info = std::make_unique<fbs::AccelerationStructureInfoNVT>(
        info_of(VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_NV, 0));
    auto geo = std::make_unique<fbs::GeometryNVT>();
    geo->geometry_type = VK_GEOMETRY_TYPE_TRIANGLES_NV;
    geo->triangles =
        std::make_unique<fbs::GeometryTrianglesNV>(v, 0, 3, uint32_t(VK_FORMAT_R32G32B32_SFLOAT),
                                                   12, i, 0, 3, uint32_t(VK_INDEX_TYPE_UINT32), 0,
                                                   0);
    geo->aabbs = std::make_unique<fbs::GeometryAabbNV>();
    b.info->geometries.push_back(std::move(geo));
    b.dst = blas.handle;
    b.scratch = scratch;
    b.inputs = std::move(inputs_);
    inputs_.clear();
    writer_.append(std::move(b));
}

void ConsumerTrace::build_top(const Object& tlas, const std::vector<Object>& blas) {
    std::vector<uint64_t> references;
    for (const Object& o : blas) references.push_back(o.driver_handle);
    const std::vector<uint8_t> instances = tb::packed_instances(references);
    const uint64_t instance_buffer = buffer(instances.data(), instances.size());
    const uint64_t scratch = buffer(nullptr, 1 << 16);
    fbs::CmdBuildAccelerationStructureNVT b;
    b.command_buffer = open();
    b.info = std::make_unique<fbs::AccelerationStructureInfoNVT>(
        info_of(VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_NV, uint32_t(blas.size())));
    b.instance_data = instance_buffer;
    b.dst = tlas.handle;
    b.scratch = scratch;
    b.inputs = std::move(inputs_);
    inputs_.clear();
    writer_.append(std::move(b));
}

void ConsumerTrace::barrier(uint64_t src_stages, uint64_t src_access, uint64_t dst_stages,
                            uint64_t dst_access) {
    writer_.append(tb::memory_barrier(open(), src_stages, src_access, dst_stages, dst_access));
}

void ConsumerTrace::trace_rays(const Object& tlas) {
    writer_.append(tb::trace_rays(open(), {tb::structure_binding(tlas.handle, 0, 0, 1)}));
}

void ConsumerTrace::trace_rays_at(uint64_t address) {
    writer_.append(tb::trace_rays(open(), {tb::structure_binding(0, address)}));
}

void ConsumerTrace::ray_query_dispatch(const Object& tlas) {
    writer_.append(tb::ray_query_dispatch(open(), {tb::structure_binding(0, tlas.driver_handle)}));
}

void ConsumerTrace::ray_query_dispatch(std::vector<fbs::AccelerationStructureBinding> structures) {
    writer_.append(tb::ray_query_dispatch(open(), std::move(structures)));
}

void ConsumerTrace::ray_query_draw(const Object& tlas, uint64_t stages) {
    writer_.append(tb::ray_query_draw(open(), stages, {tb::structure_binding(tlas.handle)}));
}

void ConsumerTrace::next_command_buffer() {
    writer_.append(tb::command_buffer_end(open()));
    ended_.push_back(command_buffer_++);
    open_ = false;
}

void ConsumerTrace::begin_secondary() {
    secondary_ = next_secondary_++;
    fbs::CommandBufferBeginT begin = tb::command_buffer_begin(secondary_);
    begin.level = 1;
    writer_.append(begin);
}

uint64_t ConsumerTrace::end_secondary() {
    const uint64_t ended = secondary_;
    writer_.append(tb::command_buffer_end(ended));
    secondary_ = 0;
    return ended;
}

void ConsumerTrace::execute_commands(std::vector<uint64_t> secondaries) {
    fbs::CmdExecuteCommandsT e;
    e.command_buffer = open();
    e.secondaries = std::move(secondaries);
    writer_.append(std::move(e));
}

void ConsumerTrace::submit(uint64_t fence) {
    next_command_buffer();
    writer_.append(tb::queue_submit(kQueue, ended_, fence, writer_.next_submission_index()));
    ended_.clear();
}

void ConsumerTrace::wait(uint64_t fence) { writer_.wait_fence(fence); }

void ConsumerTrace::present(uint64_t frame) { writer_.append(tb::queue_present(kQueue, frame)); }

void ConsumerTrace::pre_range_state(uint64_t before_frame, uint64_t prelude_submission) {
    fbs::PreRangeStateT r;
    r.queue = kQueue;
    r.before_frame = before_frame;
    r.prelude_submission = prelude_submission;
    r.structures = 2;
    r.commands = 2;
    writer_.append(r);
}

void ConsumerTrace::destroy(const Object& o) {
    fbs::AccelerationStructureDestroyT d;
    d.acceleration_structure = o.handle;
    writer_.append(d);
}

void ConsumerTrace::finish() { writer_.finish(); }

}  // namespace clastrace::consumertest
