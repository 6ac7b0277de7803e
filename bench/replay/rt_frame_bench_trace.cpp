// SPDX-License-Identifier: Apache-2.0
#include "rt_frame_bench_trace.h"

#include <clastrace/engine/khr_build.h>
#include <clastrace/engine/properties.h>
#include <clastrace/trace_building/command_records.h>
#include <clastrace/trace_building/consumer_records.h>
#include <clastrace/trace_building/khr_records.h>
#include <clastrace/trace_building/record_writer.h>
#include <clastrace/trace_building/trace_header.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <span>
#include <vector>

namespace clastrace::bench {
namespace {

namespace tb = trace_building;

constexpr uint32_t kSlots = 2;  // ring slots (frames in flight) and BLAS pool slots
constexpr uint64_t kQueue = 0x9001, kMemory = 0x1001, kFirstFence = 0xFE0;
constexpr uint64_t kFirstCommandBuffer = 0xC000, kFirstStructure = 0xA5000;
constexpr uint64_t kBase = 0x10000000;
constexpr uint64_t kSda = VK_BUFFER_USAGE_SHADER_DEVICE_ADDRESS_BIT;
constexpr uint64_t kInput = VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_BIT_KHR;
constexpr uint64_t kStorage = VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_STORAGE_BIT_KHR;
constexpr uint64_t kBuild = VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR;
constexpr uint64_t kConsumerStages =
    VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT | VK_PIPELINE_STAGE_2_RAY_TRACING_SHADER_BIT_KHR;
constexpr uint64_t kStructureRead = VK_ACCESS_2_ACCELERATION_STRUCTURE_READ_BIT_KHR;
constexpr uint64_t kStructureWrite = VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR;

uint64_t round_up(uint64_t v, uint64_t to) { return (v + to - 1) / to * to; }

struct Buffer {
    uint64_t handle = 0, address = 0, size = 0;
};

// Everything one ring slot (a frame in flight) owns, and one pool slot's BLASes.
struct RingSlot {
    Buffer staging, vertices, instances, scratch, tlas_storage;
    engine::KhrObject tlas;
    uint64_t fence = 0, command_buffer = 0;
};
struct PoolSlot {
    Buffer storage;
    std::vector<engine::KhrObject> blas;
};

class FrameLoopWriter {
public:
    FrameLoopWriter(const std::string& path, const RtFrameShape& shape);
    RtFrameStats write();

private:
    Buffer buffer(uint64_t size, uint64_t usage);
    engine::KhrObject structure(VkAccelerationStructureTypeKHR type, const Buffer& storage,
                                uint64_t offset, uint64_t size);
    engine::KhrGeometry mesh_geometry(const RingSlot& ring, uint32_t mesh) const;
    std::vector<float> animated_vertices(uint32_t frame) const;
    void barrier(const RingSlot& ring, uint64_t src_stages, uint64_t src_access,
                 uint64_t dst_stages, uint64_t dst_access);
    uint64_t record_frame(uint32_t frame);
    void setup();

    std::string path_;
    RtFrameShape shape_;
    tb::RecordWriter writer_;
    std::array<RingSlot, kSlots> ring_;
    std::array<PoolSlot, kSlots> pool_;
    uint64_t next_buffer_ = 0xB000, next_address_ = kBase, next_structure_ = kFirstStructure;
    uint64_t blas_bytes_ = 0, tlas_bytes_ = 0, blas_scratch_ = 0, tlas_scratch_ = 0;
    uint64_t working_set_ = 0;
};

fbs::TraceHeaderT header() {
    fbs::TraceHeaderT h = tb::trace_header("llvmpipe (bench double)", "llvmpipe", "rt_frame_bench");
    h.device->cluster_properties =
        tb::cluster_properties(engine::EngineProperties::nvidia_default());
    return h;
}

FrameLoopWriter::FrameLoopWriter(const std::string& path, const RtFrameShape& shape)
    : path_(path), shape_(shape), writer_(path, header()) {}

Buffer FrameLoopWriter::buffer(uint64_t size, uint64_t usage) {
    Buffer b{next_buffer_++, next_address_, size};
    next_address_ += round_up(size, 0x10000) + 0x10000;
    writer_.buffer(b.handle, b.address, size, usage | kSda, kMemory, b.address - kBase);
    working_set_ += size;
    return b;
}

engine::KhrObject FrameLoopWriter::structure(VkAccelerationStructureTypeKHR type,
                                             const Buffer& storage, uint64_t offset,
                                             uint64_t size) {
    engine::KhrObject o;
    o.handle = next_structure_++;
    o.address = storage.address + offset;
    o.size = size;
    o.type = type;
    writer_.append(tb::khr_acceleration_structure_create(o.handle, type, storage.handle, offset,
                                                         size, o.address));
    return o;
}

engine::KhrGeometry FrameLoopWriter::mesh_geometry(const RingSlot& ring, uint32_t mesh) const {
    engine::KhrGeometry g;
    g.type = VK_GEOMETRY_TYPE_TRIANGLES_KHR;
    g.flags = VK_GEOMETRY_OPAQUE_BIT_KHR;
    g.triangles.vertex_data =
        ring.vertices.address + uint64_t(mesh) * shape_.triangles_per_mesh * 36;
    g.triangles.max_vertex = shape_.triangles_per_mesh * 3 - 1;
    return g;
}

// Sizes from the engine's answer to vkGetAccelerationStructureBuildSizesKHR (what the example
// asks the driver), then the ring and the pool, as the example creates them before frame 0.
void FrameLoopWriter::setup() {
    const RingSlot probe{};
    const std::vector<engine::KhrGeometry> mesh{mesh_geometry(probe, 0)};
    const uint32_t triangles[1] = {shape_.triangles_per_mesh};
    const engine::KhrBuildSizes blas =
        engine::khr_build_sizes(VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR, mesh, triangles);
    engine::KhrGeometry instances;
    instances.type = VK_GEOMETRY_TYPE_INSTANCES_KHR;
    const uint32_t instance_count[1] = {shape_.meshes};
    const engine::KhrBuildSizes tlas =
        engine::khr_build_sizes(VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_KHR,
                                std::span(&instances, 1), instance_count);
    blas_bytes_ = round_up(blas.acceleration_structure_size, 256);
    tlas_bytes_ = round_up(tlas.acceleration_structure_size, 256);
    blas_scratch_ = round_up(blas.build_scratch_size, 256);
    tlas_scratch_ = round_up(tlas.build_scratch_size, 256);
    const uint64_t vertex_bytes = uint64_t(shape_.meshes) * shape_.triangles_per_mesh * 36;
    for (uint32_t s = 0; s < kSlots; ++s) {
        RingSlot& r = ring_[s];
        r.staging = buffer(vertex_bytes, VK_BUFFER_USAGE_TRANSFER_SRC_BIT);
        r.vertices = buffer(vertex_bytes, kInput | VK_BUFFER_USAGE_TRANSFER_DST_BIT);
        r.instances = buffer(uint64_t(shape_.meshes) * 64, kInput);
        r.scratch = buffer(blas_scratch_ * shape_.meshes + tlas_scratch_,
                           VK_BUFFER_USAGE_STORAGE_BUFFER_BIT);
        r.tlas_storage = buffer(tlas_bytes_, kStorage);
        r.tlas =
            structure(VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_KHR, r.tlas_storage, 0, tlas_bytes_);
        r.fence = kFirstFence + s;
        r.command_buffer = kFirstCommandBuffer + s;
        PoolSlot& p = pool_[s];
        p.storage = buffer(blas_bytes_ * shape_.meshes, kStorage);
        for (uint32_t m = 0; m < shape_.meshes; ++m)
            p.blas.push_back(structure(VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR, p.storage,
                                       blas_bytes_ * m, blas_bytes_));
    }
}

// Each mesh a strip of triangles whose height waves with the frame, so every frame's vertex
// upload is a new content (as the example's animation is).
std::vector<float> FrameLoopWriter::animated_vertices(uint32_t frame) const {
    std::vector<float> v;
    v.reserve(size_t(shape_.meshes) * shape_.triangles_per_mesh * 9);
    for (uint32_t m = 0; m < shape_.meshes; ++m)
        for (uint32_t t = 0; t < shape_.triangles_per_mesh; ++t) {
            const float x = float(t) * 0.5f, h = 1.0f + 0.25f * std::sin(0.1f * float(frame + t));
            const float corners[9] = {x, 0, 0, x + 1, 0, 0, x + 0.5f, h, 0};
            v.insert(v.end(), corners, corners + 9);
        }
    return v;
}

void FrameLoopWriter::barrier(const RingSlot& ring, uint64_t src_stages, uint64_t src_access,
                              uint64_t dst_stages, uint64_t dst_access) {
    writer_.append(
        tb::memory_barrier(ring.command_buffer, src_stages, src_access, dst_stages, dst_access));
}

// One frame's commands, submission and frame-end mark; returns the snapshot bytes it carries.
uint64_t FrameLoopWriter::record_frame(uint32_t frame) {
    RingSlot& r = ring_[frame % kSlots];
    const PoolSlot& p = pool_[frame % kSlots];
    if (frame >= kSlots) writer_.wait_fence(r.fence);  // frame - 2 is done with both slots
    writer_.append(tb::command_buffer_begin(r.command_buffer));
    const std::vector<float> vertices = animated_vertices(frame);
    fbs::CmdCopyBufferT copy;
    copy.command_buffer = r.command_buffer;
    copy.src_buffer = r.staging.handle;
    copy.dst_buffer = r.vertices.handle;
    copy.regions.emplace_back(0, 0, r.staging.size);
    copy.inputs.push_back(writer_.snapshot(r.staging.address, vertices.data(), vertices.size() * 4,
                                           r.staging.handle));
    writer_.append(std::move(copy));
    barrier(r, VK_PIPELINE_STAGE_2_COPY_BIT, VK_ACCESS_2_TRANSFER_WRITE_BIT, kBuild,
            VK_ACCESS_2_SHADER_READ_BIT | kStructureRead);
    engine::KhrBuildCommand blas_build;
    for (uint32_t m = 0; m < shape_.meshes; ++m) {
        engine::KhrBuildInfo info;
        info.dst = p.blas[m];
        info.geometries.push_back(mesh_geometry(r, m));
        info.ranges.push_back({shape_.triangles_per_mesh, 0, 0, 0});
        info.scratch_address = r.scratch.address + blas_scratch_ * m;
        blas_build.infos.push_back(std::move(info));
    }
    writer_.append(tb::khr_build(r.command_buffer, blas_build));
    barrier(r, kBuild, kStructureWrite, kBuild, kStructureRead);
    std::vector<uint8_t> instances;
    for (uint32_t m = 0; m < shape_.meshes; ++m) {
        const std::array<float, 12> placed = {1, 0, 0, 0, 0, 1, 0, 2.0f * float(m), 0, 0, 1, 0};
        const auto bytes = tb::instance_bytes(placed, m, 0xFF, 0, 0, p.blas[m].address);
        instances.insert(instances.end(), bytes.begin(), bytes.end());
    }
    engine::KhrBuildInfo top;
    top.type = VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_KHR;
    top.dst = r.tlas;
    engine::KhrGeometry g;
    g.type = VK_GEOMETRY_TYPE_INSTANCES_KHR;
    g.instances.data = r.instances.address;
    top.geometries.push_back(g);
    top.ranges.push_back({shape_.meshes, 0, 0, 0});
    top.scratch_address = r.scratch.address + blas_scratch_ * shape_.meshes;
    engine::KhrBuildCommand top_build;
    top_build.infos.push_back(std::move(top));
    fbs::CmdBuildAccelerationStructuresKHRT tlas_build = tb::khr_build(r.command_buffer, top_build);
    tlas_build.inputs.push_back(writer_.snapshot(r.instances.address, instances.data(),
                                                 instances.size(), r.instances.handle));
    writer_.append(std::move(tlas_build));
    barrier(r, kBuild, kStructureWrite, kConsumerStages, kStructureRead);
    const std::vector<fbs::AccelerationStructureBinding> bound{
        tb::structure_binding(r.tlas.handle, r.tlas.address)};
    if (frame % 2 == 0)
        writer_.append(tb::ray_query_dispatch(r.command_buffer, bound));
    else
        writer_.append(
            tb::trace_rays(r.command_buffer, bound, shape_.ray_width, shape_.ray_height));
    barrier(r, kConsumerStages, VK_ACCESS_2_SHADER_WRITE_BIT, VK_PIPELINE_STAGE_2_HOST_BIT,
            VK_ACCESS_2_HOST_READ_BIT);
    const uint64_t submission = writer_.next_submission_index();
    writer_.end_and_submit(kQueue, r.command_buffer, r.fence);
    fbs::FrameBoundaryT mark;
    mark.queue = kQueue;
    mark.carrier = 0;
    mark.submission = submission;
    mark.flags = 1;  // VK_FRAME_BOUNDARY_FRAME_END_BIT_EXT
    mark.frame_id = frame;
    mark.frame = frame;
    writer_.append(std::move(mark));
    return vertices.size() * 4 + instances.size();
}

RtFrameStats FrameLoopWriter::write() {
    setup();
    RtFrameStats stats;
    for (uint32_t frame = 0; frame < shape_.frames; ++frame)
        stats.largest_frame_snapshot_bytes =
            std::max(stats.largest_frame_snapshot_bytes, record_frame(frame));
    for (const RingSlot& r : ring_) writer_.wait_fence(r.fence);
    const traces::TraceWriterStats written = writer_.finish();
    stats.frames = shape_.frames;
    stats.submissions = written.submissions;
    stats.file_bytes = std::filesystem::file_size(path_);
    stats.working_set_bytes = working_set_;
    return stats;
}

}  // namespace

RtFrameStats write_rt_frame_trace(const std::string& path, const RtFrameShape& shape) {
    return FrameLoopWriter(path, shape).write();
}

}  // namespace clastrace::bench
