// SPDX-License-Identifier: Apache-2.0
#include "nv_trace_builder.h"

#include <clastrace/trace_building/command_records.h>
#include <clastrace/trace_building/trace_header.h>

namespace clastrace::nvtest {
namespace {

namespace tb = trace_building;

constexpr uint64_t kQueue = 0x9001, kFence = 0xFE1, kBufferMemory = 0x1001, kObjectMemory = 0x1002;

fbs::TraceHeaderT nv_header(bool engine_device, uint64_t max_instance_count,
                            std::vector<std::string> enabled_extensions) {
    fbs::TraceHeaderT h =
        tb::trace_header(engine_device ? tb::kEngineDriver : "NVIDIA H100 (test double)",
                         engine_device ? tb::kEngineDriver : "NVIDIA", "replay_nv_tests");
    h.device->enabled_extensions = std::move(enabled_extensions);
    if (max_instance_count) {
        h.device->ray_tracing_properties_nv = std::make_unique<fbs::RayTracingPropertiesNVT>();
        h.device->ray_tracing_properties_nv->max_instance_count = max_instance_count;
    }
    return h;
}

}  // namespace

NvTraceBuilder::NvTraceBuilder(const std::string& path, bool engine_device,
                               uint64_t max_instance_count,
                               std::vector<std::string> enabled_extensions)
    : writer_(path, nv_header(engine_device, max_instance_count, std::move(enabled_extensions))) {}

NvTraceBuilder::~NvTraceBuilder() = default;

uint64_t NvTraceBuilder::buffer(const void* bytes, uint64_t size, uint64_t usage) {
    const uint64_t handle = next_buffer_++, address = next_address_;
    next_address_ += (size + 0xFFFF) / 0x10000 * 0x10000 + 0x10000;
    writer_.buffer(handle, address, size, usage | VK_BUFFER_USAGE_SHADER_DEVICE_ADDRESS_BIT,
                   kBufferMemory, address - 0x10000000);
    buffers_.push_back({handle, address});
    if (bytes) pending_inputs_.push_back(writer_.snapshot(address, bytes, size, handle));
    return handle;
}

uint64_t NvTraceBuilder::address_of(uint64_t buffer) const {
    for (const auto& [h, a] : buffers_)
        if (h == buffer) return a;
    return 0;
}

NvTraceBuilder::Object NvTraceBuilder::create(const fbs::AccelerationStructureInfoNVT& info,
                                              uint64_t driver_object_size, bool bind) {
    Object o;
    o.handle = next_object_++;
    o.driver_handle = 0x7F00'0000'0000ull +
                      o.handle * 0x1000;  // what vkGetAccelerationStructureHandleNV answered
    fbs::AccelerationStructureCreateT c;
    c.acceleration_structure = o.handle;
    c.api = 0;
    c.type = info.type;
    c.info = std::make_unique<fbs::AccelerationStructureInfoNVT>(info);
    c.device_address = o.driver_handle;
    writer_.append(std::move(c));
    for (uint32_t type : {0u, 1u, 2u}) {
        fbs::AccelerationStructureMemoryRequirementsNVT q;
        q.acceleration_structure = o.handle;
        q.type = type;
        q.size = type == 0 ? driver_object_size : 4096;
        q.alignment = 256;
        writer_.append(q);
    }
    if (bind) {
        fbs::AccelerationStructureBindMemoryT b;
        b.acceleration_structure = o.handle;
        b.memory = kObjectMemory;
        b.memory_offset = next_offset_;
        next_offset_ += (driver_object_size + 0xFFFF) / 0x10000 * 0x10000;
        writer_.append(b);
    }
    return o;
}

fbs::AccelerationStructureInfoNVT NvTraceBuilder::blas_info(const BlasSpec& spec, uint32_t flags) {
    fbs::AccelerationStructureInfoNVT info;
    info.type = VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_NV;
    info.flags = flags;
    for (const GeometrySpec& g : spec.geometries) {
        auto geo = std::make_unique<fbs::GeometryNVT>();
        geo->flags = g.flags;
        if (spec.aabbs) {
            geo->geometry_type = VK_GEOMETRY_TYPE_AABBS_NV;
            const uint64_t b = buffer(g.boxes.data(), g.boxes.size() * 24);
            geo->aabbs = std::make_unique<fbs::GeometryAabbNV>(b, uint32_t(g.boxes.size()), 24, 0);
            geo->triangles = std::make_unique<fbs::GeometryTrianglesNV>();
        } else {
            geo->geometry_type = VK_GEOMETRY_TYPE_TRIANGLES_NV;
            const uint64_t v = buffer(g.mesh.positions.data(), g.mesh.positions.size() * 12);
            const uint64_t i = buffer(g.mesh.triangles.data(), g.mesh.triangles.size() * 12);
            geo->triangles = std::make_unique<fbs::GeometryTrianglesNV>(
                v, 0, uint32_t(g.mesh.positions.size()), uint32_t(VK_FORMAT_R32G32B32_SFLOAT), 12,
                i, 0, uint32_t(g.mesh.triangles.size() * 3), uint32_t(VK_INDEX_TYPE_UINT32), 0, 0);
            geo->aabbs = std::make_unique<fbs::GeometryAabbNV>();
        }
        info.geometries.push_back(std::move(geo));
    }
    return info;
}

fbs::AccelerationStructureInfoNVT NvTraceBuilder::tlas_info(uint32_t instance_count,
                                                            uint32_t flags) {
    fbs::AccelerationStructureInfoNVT info;
    info.type = VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_NV;
    info.flags = flags;
    info.instance_count = instance_count;
    return info;
}

void NvTraceBuilder::build(const fbs::AccelerationStructureInfoNVT& info, const Object& dst,
                           uint64_t instance_buffer, bool update, const Object* src,
                           uint64_t scratch_size, uint64_t scratch_buffer) {
    const uint64_t scratch = scratch_buffer ? scratch_buffer : buffer(nullptr, scratch_size);
    begin_if_needed();
    fbs::CmdBuildAccelerationStructureNVT b;
    b.command_buffer = command_buffer_;
    b.info = std::make_unique<fbs::AccelerationStructureInfoNVT>(info);
    b.instance_data = instance_buffer;
    b.update = update;
    b.dst = dst.handle;
    b.src = src ? src->handle : 0;
    b.scratch = scratch;
    b.inputs = std::move(pending_inputs_);
    pending_inputs_.clear();
    writer_.append(std::move(b));
}

void NvTraceBuilder::begin_if_needed() {
    if (open_) return;
    writer_.append(tb::command_buffer_begin(command_buffer_));
    open_ = true;
}

void NvTraceBuilder::deserialize(uint64_t src_buffer, const Object& dst, uint32_t mode,
                                 uint64_t src_offset) {
    begin_if_needed();
    fbs::CmdCopyMemoryToAccelerationStructureT c;
    c.command_buffer = command_buffer_;
    c.src_address = address_of(src_buffer) + src_offset;
    c.dst = dst.handle;
    c.mode = mode;
    c.inputs = std::move(pending_inputs_);
    pending_inputs_.clear();
    writer_.append(std::move(c));
}

void NvTraceBuilder::barrier() {
    const uint64_t stages = VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR |
                            VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_COPY_BIT_KHR;
    const uint64_t access = VK_ACCESS_2_ACCELERATION_STRUCTURE_READ_BIT_KHR |
                            VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR |
                            VK_ACCESS_2_SHADER_READ_BIT | VK_ACCESS_2_TRANSFER_READ_BIT;
    writer_.append(tb::memory_barrier(command_buffer_, stages, access, stages, access));
}

void NvTraceBuilder::submit() {
    writer_.end_and_submit(kQueue, command_buffer_, kFence);
    writer_.wait_fence(kFence);
    ++command_buffer_;
    open_ = false;
}

void NvTraceBuilder::ray_check(const Object& tlas, const std::vector<eng::Ray>& rays,
                               const std::vector<uint32_t>& flags,
                               const std::vector<uint32_t>& masks,
                               const std::vector<RefHit>& answers, const std::string& label) {
    fbs::RayQueryCheckT c;
    c.acceleration_structure = tlas.handle;
    c.device_handle = tlas.driver_handle;
    c.after_submission = writer_.next_submission_index() - 1;
    c.label = label;
    for (size_t i = 0; i < rays.size(); ++i) {
        const eng::Ray& r = rays[i];
        c.rays.emplace_back(r.origin[0], r.origin[1], r.origin[2], r.tmin, r.direction[0],
                            r.direction[1], r.direction[2], r.tmax, flags[i], masks[i]);
        const RefHit& a = answers[i];
        c.results.emplace_back(a.hit ? 1u : 0u, a.t, a.custom_index, a.instance, a.primitive,
                               a.geometry, a.hit_kind, a.u, a.v);
    }
    writer_.append(std::move(c));
}

void NvTraceBuilder::finish() { writer_.finish(); }

}  // namespace clastrace::nvtest
