// SPDX-License-Identifier: Apache-2.0
#include "khr_trace.h"

#include "trace_files.h"

#include <clastrace/trace_building/cluster_records.h>
#include <clastrace/trace_building/cluster_structs.h>
#include <clastrace/trace_building/command_records.h>
#include <clastrace/trace_building/khr_records.h>
#include <clastrace/trace_building/trace_header.h>

#include <cstring>
#include <sstream>

namespace clastrace::khrtest {
namespace {

namespace tb = trace_building;

constexpr uint64_t kQueue = 0x9001, kFence = 0xFE1, kMemory = 0x1001, kObjectMemory = 0x1002;
constexpr uint64_t kSda = VK_BUFFER_USAGE_SHADER_DEVICE_ADDRESS_BIT;
constexpr uint64_t kInput = VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_BIT_KHR;
constexpr uint64_t kStorage = VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_STORAGE_BIT_KHR;
// What every buffer of a cluster build may be used as (its rules name each usage).
constexpr uint64_t kClusterBuffers = kInput | kStorage | VK_BUFFER_USAGE_STORAGE_BUFFER_BIT;

fbs::TraceHeaderT header(bool engine_device) {
    fbs::TraceHeaderT h =
        tb::trace_header(engine_device ? tb::kEngineDriver : "llvmpipe (test double)",
                         engine_device ? tb::kEngineDriver : "llvmpipe", "replay_khr_tests");
    h.device->cluster_properties =
        tb::cluster_properties(engine::EngineProperties::nvidia_default());
    return h;
}

}  // namespace

std::vector<float> triangle_vertices() { return {0, 0, 0, 1, 0, 0, 0, 1, 0}; }

CheckedRay ray_through(float x, float y, uint32_t instance) {
    CheckedRay r;
    // Instances sit 10 apart along x: the weights of v1 and v2 are the local x and y.
    r.u = x - 10.0f * float(instance);
    r.v = y;
    r.origin = {x, y, -5.0f};
    r.direction = {0.0f, 0.0f, 1.0f};
    r.t = 5.0f;
    r.instance = instance;
    // Seen along +z, (0,0,0) (1,0,0) (0,1,0) runs counterclockwise: back-facing (0xFF).
    r.hit_kind = 0xFF;
    return r;
}

KhrTrace::KhrTrace(const std::string& path, bool engine_device)
    : path_(path), writer_(path, header(engine_device)) {}

uint64_t KhrTrace::buffer(const void* bytes, uint64_t size, uint64_t usage) {
    const uint64_t handle = next_buffer_++, address = next_address_;
    next_address_ += (size + 0xFFFF) / 0x10000 * 0x10000 + 0x10000;
    writer_.buffer(handle, address, size, usage | kSda, kMemory, address - 0x10000000);
    buffers_.push_back({handle, address});
    if (bytes) pending_.push_back(writer_.snapshot(address, bytes, size, handle));
    return handle;
}

uint64_t KhrTrace::address_of(uint64_t buffer) const {
    for (const auto& [h, a] : buffers_)
        if (h == buffer) return a;
    return 0;
}

std::vector<fbs::MemorySnapshot> KhrTrace::take_inputs() {
    std::vector<fbs::MemorySnapshot> out = std::move(pending_);
    pending_.clear();
    return out;
}

uint64_t KhrTrace::scratch() { return address_of(buffer(nullptr, 1 << 20, kClusterBuffers)); }

KhrTrace::Object KhrTrace::create(VkAccelerationStructureTypeKHR type, uint64_t size) {
    const uint64_t storage = buffer(nullptr, size, kStorage);
    Object o{next_object_++, address_of(storage)};
    writer_.append(
        tb::khr_acceleration_structure_create(o.handle, type, storage, 0, size, o.address));
    return o;
}

engine::KhrBuildInfo KhrTrace::triangle_blas(const Object& dst, uint64_t vertex_buffer) {
    const std::vector<float> v = triangle_vertices();
    if (vertex_buffer == 0) vertex_buffer = buffer(v.data(), v.size() * 4, kInput);
    engine::KhrBuildInfo info;
    info.type = VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR;
    info.dst.handle = dst.handle;
    engine::KhrGeometry g;
    g.type = VK_GEOMETRY_TYPE_TRIANGLES_KHR;
    g.flags = VK_GEOMETRY_OPAQUE_BIT_KHR;
    g.triangles.vertex_data = address_of(vertex_buffer);
    g.triangles.max_vertex = 2;
    info.geometries.push_back(g);
    info.ranges.push_back({1, 0, 0, 0});
    info.scratch_address = scratch();
    return info;
}

engine::KhrBuildInfo KhrTrace::top_level(const Object& dst,
                                         const std::vector<std::array<uint8_t, 64>>& instances) {
    const uint64_t records = buffer(instances.data(), instances.size() * 64, kInput);
    engine::KhrBuildInfo info;
    info.type = VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_KHR;
    info.dst.handle = dst.handle;
    engine::KhrGeometry g;
    g.type = VK_GEOMETRY_TYPE_INSTANCES_KHR;
    g.instances.data = address_of(records);
    info.geometries.push_back(g);
    info.ranges.push_back({uint32_t(instances.size()), 0, 0, 0});
    info.scratch_address = scratch();
    return info;
}

void KhrTrace::build(const engine::KhrBuildCommand& command) {
    begin_if_needed();
    fbs::CmdBuildAccelerationStructuresKHRT b = tb::khr_build(command_buffer_, command);
    b.inputs = take_inputs();
    writer_.append(std::move(b));
}

KhrTrace::Object KhrTrace::nv_triangle_blas() {
    const std::vector<float> v = triangle_vertices();
    const uint64_t vertices = buffer(v.data(), v.size() * 4, VK_BUFFER_USAGE_RAY_TRACING_BIT_NV);
    const uint64_t scratch_buffer = buffer(nullptr, 1 << 20, VK_BUFFER_USAGE_RAY_TRACING_BIT_NV);
    fbs::AccelerationStructureInfoNVT info;
    info.type = VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_NV;
    auto geo = std::make_unique<fbs::GeometryNVT>();
    geo->geometry_type = VK_GEOMETRY_TYPE_TRIANGLES_NV;
    geo->flags = VK_GEOMETRY_OPAQUE_BIT_NV;
    geo->triangles =
        std::make_unique<fbs::GeometryTrianglesNV>(vertices, 0, 3,
                                                   uint32_t(VK_FORMAT_R32G32B32_SFLOAT), 12, 0, 0,
                                                   0, uint32_t(VK_INDEX_TYPE_NONE_NV), 0, 0);
    geo->aabbs = std::make_unique<fbs::GeometryAabbNV>();
    info.geometries.push_back(std::move(geo));
    Object o{next_object_++, 0};
    o.address = 0x7F00'0000'0000ull + o.handle * 0x1000;  // vkGetAccelerationStructureHandleNV
    fbs::AccelerationStructureCreateT c;
    c.acceleration_structure = o.handle;
    c.api = 0;
    c.type = info.type;
    c.info = std::make_unique<fbs::AccelerationStructureInfoNVT>(info);
    c.device_address = o.address;
    writer_.append(std::move(c));
    fbs::AccelerationStructureBindMemoryT bind;
    bind.acceleration_structure = o.handle;
    bind.memory = kObjectMemory;
    writer_.append(bind);
    begin_if_needed();
    fbs::CmdBuildAccelerationStructureNVT b;
    b.command_buffer = command_buffer_;
    b.info = std::make_unique<fbs::AccelerationStructureInfoNVT>(info);
    b.dst = o.handle;
    b.scratch = scratch_buffer;
    b.inputs = take_inputs();
    writer_.append(std::move(b));
    return o;
}

uint64_t KhrTrace::cluster_triangle_blas(bool null_reference, uint64_t driver_address) {
    // The CLAS: one triangle over three vertices, at an explicit destination.
    const std::vector<float> v = triangle_vertices();
    const uint8_t indices[3] = {0, 1, 2};
    const uint64_t vertices = address_of(buffer(v.data(), v.size() * 4, kClusterBuffers));
    const uint64_t index_buffer = address_of(buffer(indices, sizeof indices, kClusterBuffers));
    const uint64_t clas = address_of(buffer(nullptr, 1 << 16, kClusterBuffers));
    const auto cluster = tb::triangle_cluster_info(7, 1, 3, index_buffer, 1, vertices);
    const uint64_t cluster_info = address_of(buffer(&cluster, sizeof cluster, kClusterBuffers));
    const uint64_t clas_destination = address_of(buffer(&clas, 8, kClusterBuffers));
    const auto limits = tb::triangle_cluster_limits(1, 3, 1, 3);
    const auto clas_input =
        tb::cluster_op_input(1, &limits,
                             VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_EXPLICIT_DESTINATIONS_NV);
    VkClusterAccelerationStructureCommandsInfoNV clas_build = tb::cluster_commands(clas_input);
    clas_build.scratchData = scratch();
    clas_build.dstAddressesArray = {clas_destination, 8, 8};
    clas_build.srcInfosArray = {cluster_info, sizeof cluster, sizeof cluster};
    begin_if_needed();
    auto clas_record = tb::cluster_build(command_buffer_, clas_build);
    clas_record.inputs = take_inputs();
    writer_.append(std::move(clas_record));
    build_barrier();
    // The BLAS over it (and a null reference when asked).
    std::vector<uint64_t> references{clas};
    if (null_reference) references.push_back(0);
    const uint64_t reference_buffer =
        address_of(buffer(references.data(), references.size() * 8, kClusterBuffers));
    VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV bottom{};
    bottom.clusterReferencesCount = uint32_t(references.size());
    bottom.clusterReferencesStride = 8;
    bottom.clusterReferences = reference_buffer;
    const uint64_t bottom_info = address_of(buffer(&bottom, sizeof bottom, kClusterBuffers));
    const uint64_t blas = address_of(buffer(nullptr, 1 << 16, kClusterBuffers));
    const bool implicit = driver_address != 0;
    const uint64_t destination_buffer =
        buffer(implicit ? nullptr : &blas, 8, kClusterBuffers);  // implicit: the command writes it
    const uint64_t blas_destination = address_of(destination_buffer);
    VkClusterAccelerationStructureClustersBottomLevelInputNV bottom_limits{};
    bottom_limits.sType =
        VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_CLUSTERS_BOTTOM_LEVEL_INPUT_NV;
    bottom_limits.maxTotalClusterCount = 16;
    bottom_limits.maxClusterCountPerAccelerationStructure = 16;
    const auto blas_input = tb::cluster_op_input(
        1, &bottom_limits,
        implicit ? VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV
                 : VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_EXPLICIT_DESTINATIONS_NV);
    VkClusterAccelerationStructureCommandsInfoNV blas_build = tb::cluster_commands(blas_input);
    blas_build.scratchData = scratch();
    blas_build.dstAddressesArray = {blas_destination, 8, 8};
    blas_build.srcInfosArray = {bottom_info, sizeof bottom, sizeof bottom};
    if (implicit) blas_build.dstImplicitData = blas;
    auto blas_record = tb::cluster_build(command_buffer_, blas_build);
    blas_record.inputs = take_inputs();
    if (implicit)
        blas_record.outputs.push_back(
            writer_.snapshot(blas_destination, &driver_address, 8, destination_buffer));
    writer_.append(std::move(blas_record));
    return implicit ? driver_address : blas;
}

void KhrTrace::copy_buffer(uint64_t src, uint64_t dst, uint64_t size) {
    begin_if_needed();
    fbs::CmdCopyBufferT c;
    c.command_buffer = command_buffer_;
    c.src_buffer = src;
    c.dst_buffer = dst;
    c.regions.emplace_back(0, 0, size);
    c.inputs = take_inputs();
    writer_.append(std::move(c));
}

void KhrTrace::barrier(uint64_t src_stages, uint64_t src_access, uint64_t dst_stages,
                       uint64_t dst_access) {
    begin_if_needed();
    writer_.append(
        tb::memory_barrier(command_buffer_, src_stages, src_access, dst_stages, dst_access));
}

void KhrTrace::build_barrier() {
    const uint64_t stages = VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR |
                            VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_COPY_BIT_KHR;
    const uint64_t access = VK_ACCESS_2_ACCELERATION_STRUCTURE_READ_BIT_KHR |
                            VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR |
                            VK_ACCESS_2_SHADER_READ_BIT | VK_ACCESS_2_TRANSFER_WRITE_BIT;
    barrier(stages, access, stages, access);
}

void KhrTrace::begin_if_needed() {
    if (open_) return;
    writer_.append(tb::command_buffer_begin(command_buffer_));
    open_ = true;
}

void KhrTrace::submit() {
    writer_.end_and_submit(kQueue, command_buffer_, kFence);
    writer_.wait_fence(kFence);
    ++command_buffer_;
    open_ = false;
}

void KhrTrace::ray_check(const Object& tlas, const std::vector<CheckedRay>& rays) {
    fbs::RayQueryCheckT c;
    c.acceleration_structure = tlas.handle;
    c.after_submission = writer_.next_submission_index() - 1;
    c.label = "replay_khr";
    for (const CheckedRay& r : rays) {
        c.rays.emplace_back(r.origin[0], r.origin[1], r.origin[2], 0.0f, r.direction[0],
                            r.direction[1], r.direction[2], 100.0f, 0u, 0xFFu);
        c.results.emplace_back(r.hit ? 1u : 0u, r.t, 0u, r.instance, r.primitive, 0xFFFFFFFFu,
                               r.hit_kind, r.u, r.v);
    }
    writer_.append(std::move(c));
}

replay::ReplayReport KhrTrace::replay() {
    writer_.finish();
    replay::ReplayReport r = test::replay_file(path_);
    std::remove(path_.c_str());
    return r;
}

size_t count_rule(const replay::ReplayReport& r, const std::string& rule) {
    size_t n = 0;
    for (const auto& f : r.findings) n += f.rule == rule;
    for (const auto& note : r.notes) n += note.rule == rule;
    return n;
}

std::string describe(const replay::ReplayReport& r) {
    std::ostringstream s;
    for (const auto& f : r.findings) s << "finding " << f.format() << "\n";
    for (const auto& n : r.notes) s << "note " << n.rule << ": " << n.message << "\n";
    for (const auto& h : r.hazards) s << "hazard " << h.format() << "\n";
    for (const auto& c : r.ray_checks)
        s << "ray check: rays " << c.rays << " hit " << c.agree_hit << " miss " << c.agree_miss
          << " disagree " << c.disagree << " " << c.why_not << "\n";
    return s.str();
}

}  // namespace clastrace::khrtest
