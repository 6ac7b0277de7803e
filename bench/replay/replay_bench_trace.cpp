// SPDX-License-Identifier: Apache-2.0
#include "replay_bench_trace.h"

#include <clastrace/engine/build_sizes.h>
#include <clastrace/engine/properties.h>
#include <clastrace/trace_building/cluster_records.h>
#include <clastrace/trace_building/cluster_structs.h>
#include <clastrace/trace_building/command_records.h>
#include <clastrace/trace_building/record_writer.h>
#include <clastrace/trace_building/trace_header.h>

#include <cstdio>
#include <random>
#include <stdexcept>
#include <vector>

namespace clastrace::bench {

namespace {

namespace tb = trace_building;
using tb::record;
using tb::throw_if_error;
using Info = VkClusterAccelerationStructureBuildTriangleClusterInfoNV;
using BlasInfo = VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV;

constexpr uint64_t kQueue = 0x9001, kDeviceMemory = 0x1001, kHostMemory = 0x1002;
constexpr uint64_t kCommandBuffer0 = 0xc000, kFence0 = 0xfe00;
constexpr uint32_t kSlots = 2;         // frames in flight
constexpr uint32_t kMoveEvery = 4;     // frames between cluster moves
constexpr uint32_t kStreamEvery = 16;  // frames between re-creations of the move buffer

constexpr uint64_t kSda = VK_BUFFER_USAGE_SHADER_DEVICE_ADDRESS_BIT;
constexpr uint64_t kInput =
    kSda | VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_BIT_KHR;
constexpr uint64_t kStorage = kSda | VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_STORAGE_BIT_KHR |
                              VK_BUFFER_USAGE_STORAGE_BUFFER_BIT;

constexpr uint64_t kBuild = VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR;
constexpr uint64_t kTransfer = VK_PIPELINE_STAGE_2_ALL_TRANSFER_BIT;
constexpr uint64_t kAsRead =
    VK_ACCESS_2_ACCELERATION_STRUCTURE_READ_BIT_KHR | VK_ACCESS_2_SHADER_READ_BIT;
constexpr uint64_t kAsWrite =
    VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR | VK_ACCESS_2_SHADER_WRITE_BIT;
constexpr uint64_t kBuildReads = kAsRead | VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT;

uint64_t align_up(uint64_t v, uint64_t a) { return (v + a - 1) / a * a; }

struct ClusterGeometry {
    uint64_t vertex_offset = 0, index_offset = 0;
    uint32_t vertices = 0, triangles = 0;
};

class Writer {
public:
    Writer(const std::string& path, const BenchTraceShape& shape)
        : shape_(shape), rng_(shape.seed), writer_(path, header()) {}

    BenchTraceStats run() {
        make_geometry();
        make_buffers();
        for (uint64_t frame = 0; stats_.ops < shape_.target_ops; ++frame) write_frame(frame);
        fbs::FenceWaitT wait;
        for (uint32_t s = 0; s < kSlots; ++s) wait.fences.push_back(kFence0 + s);
        wait.wait_all = true;
        append(record(std::move(wait)));
        stats_.contents = writer_.finish().contents_stored;
        return stats_;
    }

private:
    static fbs::TraceHeaderT header() {
        fbs::TraceHeaderT h =
            tb::trace_header(tb::kEngineDriver, tb::kEngineDriver, "replay_throughput_bench");
        h.device->cluster_properties =
            tb::cluster_properties(engine::EngineProperties::nvidia_default());
        return h;
    }

    // Packed here so the submission's record bytes can be counted exactly.
    void append(const fbs::RecordT& r) {
        flatbuffers::FlatBufferBuilder fbb;
        fbb.Finish(fbs::Record::Pack(fbb, &r));
        submission_bytes_ += fbb.GetSize();
        throw_if_error(writer_.writer().append_record_bytes(fbb.GetBufferPointer(), fbb.GetSize()));
    }

    fbs::MemorySnapshot snapshot(uint64_t address, const void* bytes, size_t size) {
        submission_bytes_ += size;
        return writer_.snapshot(address, bytes, size);
    }

    uint64_t add_buffer(uint64_t address, uint64_t size, uint64_t usage, uint64_t memory) {
        const uint64_t handle = next_buffer_++;
        append(record(tb::buffer_create(handle, size, usage)));
        append(record(tb::buffer_bind(handle, memory, address - 0x100000000ull, address)));
        return handle;
    }

    // Clusters are grids of 8 x (4..8) quads: 64-128 triangles, 45-81 vertices.
    void make_geometry() {
        std::uniform_int_distribution<uint32_t> rows(4, 8);
        std::uniform_real_distribution<float> jitter(-0.2f, 0.2f);
        for (uint32_t c = 0; c < shape_.cluster_pool; ++c) {
            const uint32_t w = 8, h = rows(rng_);
            ClusterGeometry g;
            g.vertex_offset = vertices_.size() * 4;
            g.index_offset = indices_.size();
            g.vertices = (w + 1) * (h + 1);
            g.triangles = 2 * w * h;
            const float ox = float(c % 16) * 10.0f, oy = float(c / 16) * 10.0f;
            for (uint32_t y = 0; y <= h; ++y)
                for (uint32_t x = 0; x <= w; ++x) {
                    vertices_.push_back(ox + float(x) + jitter(rng_));
                    vertices_.push_back(oy + float(y) + jitter(rng_));
                    vertices_.push_back(jitter(rng_) * 4.0f);
                }
            for (uint32_t y = 0; y < h; ++y)
                for (uint32_t x = 0; x < w; ++x) {
                    const auto a = uint8_t(y * (w + 1) + x), b = uint8_t(a + 1),
                               d = uint8_t(a + w + 1), e = uint8_t(d + 1);
                    for (uint8_t v : {a, b, d, b, e, d}) indices_.push_back(v);
                }
            geometry_.push_back(g);
        }
    }

    void make_buffers() {
        const engine::EngineProperties props = engine::EngineProperties::nvidia_default();
        const uint32_t k = shape_.clusters_per_build;
        const uint32_t per_frame = k * shape_.builds_per_frame;

        tri_ = tb::triangle_cluster_limits(128, 81, 128 * k, 81 * k);
        blas_in_.sType =
            VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_CLUSTERS_BOTTOM_LEVEL_INPUT_NV;
        blas_in_.maxTotalClusterCount = per_frame;
        blas_in_.maxClusterCountPerAccelerationStructure = per_frame;
        move_in_.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_MOVE_OBJECTS_INPUT_NV;
        move_in_.type = VK_CLUSTER_ACCELERATION_STRUCTURE_TYPE_TRIANGLE_CLUSTER_NV;
        move_in_.noMoveOverlap = VK_TRUE;

        const engine::BuildSizes clas = engine::cluster_build_sizes(clas_input(k), props);
        const engine::BuildSizes blas = engine::cluster_build_sizes(blas_input(), props);
        clas_bytes_ = align_up(clas.acceleration_structure_size, 256);
        move_in_.maxMovedBytes = clas.acceleration_structure_size;
        const engine::BuildSizes move = engine::cluster_build_sizes(move_input(k), props);
        blas_bytes_ = align_up(blas.acceleration_structure_size, 256);
        const uint64_t scratch =
            align_up(std::max({clas.build_scratch_size, blas.build_scratch_size,
                               move.build_scratch_size}),
                     256);
        for (const auto& [input, sizes] :
             {std::pair{clas_input(k), clas}, {blas_input(), blas}, {move_input(k), move}}) {
            fbs::GetClusterBuildSizesT q;
            q.input = tb::cluster_input(input);
            q.acceleration_structure_size = sizes.acceleration_structure_size;
            q.build_scratch_size = sizes.build_scratch_size;
            append(record(std::move(q)));
        }

        uint64_t at = 0x100000000ull;
        auto place = [&](uint64_t size, uint64_t usage, uint64_t memory, uint64_t* handle) {
            const uint64_t address = at;
            *handle = add_buffer(address, size, usage, memory);
            at = align_up(at + size, 0x10000);
            return address;
        };
        vertex_address_ = place(vertices_.size() * 4, kInput, kDeviceMemory, &vertex_buffer_);
        index_address_ = place(indices_.size(), kInput, kDeviceMemory, &index_buffer_);
        scratch_address_ = place(scratch, kStorage, kDeviceMemory, &scratch_buffer_);
        staging_address_ =
            place(kSlots * per_frame * sizeof(Info), VK_BUFFER_USAGE_TRANSFER_SRC_BIT | kSda,
                  kHostMemory, &staging_buffer_);
        for (uint32_t s = 0; s < kSlots; ++s) {
            Slot& slot = slots_[s];
            slot.infos =
                place(per_frame * sizeof(Info) + 256, kInput | VK_BUFFER_USAGE_TRANSFER_DST_BIT,
                      kDeviceMemory, &slot.infos_buffer);
            slot.clas = place(clas_bytes_ * shape_.builds_per_frame, kStorage, kDeviceMemory,
                              &slot.clas_buffer);
            // Also read as build input: BLAS cluster references and move sources point here.
            slot.addresses = place((per_frame + k + 1) * 8, kStorage | kInput, kDeviceMemory,
                                   &slot.addresses_buffer);
            slot.sizes = place((per_frame + k + 1) * 4, kStorage | VK_BUFFER_USAGE_TRANSFER_DST_BIT,
                               kDeviceMemory, &slot.sizes_buffer);
            slot.blas = place(blas_bytes_, kStorage, kDeviceMemory, &slot.blas_buffer);
        }
        stream_bytes_ = align_up(move.acceleration_structure_size, 256) * kSlots;
        stream_at_ = align_up(at, 0x100000) + 0x1000000;
        stream_address_ = stream_at_;
        stream_buffer_ = add_buffer(stream_address_, stream_bytes_, kStorage, kDeviceMemory);
        stream_at_ += align_up(stream_bytes_, 0x100000);
    }

    VkClusterAccelerationStructureInputInfoNV clas_input(uint32_t k) const {
        return tb::cluster_op_input(k, &tri_);
    }
    VkClusterAccelerationStructureInputInfoNV blas_input() const {
        return tb::cluster_op_input(1, &blas_in_);
    }
    VkClusterAccelerationStructureInputInfoNV move_input(uint32_t k) const {
        return tb::cluster_op_input(k, &move_in_);
    }

    void barrier(uint64_t src_stage, uint64_t src_access, uint64_t dst_stage, uint64_t dst_access) {
        append(record(
            tb::memory_barrier(command_buffer_, src_stage, src_access, dst_stage, dst_access)));
        ++stats_.ops;
        ++stats_.commands;
    }

    void build(const VkClusterAccelerationStructureInputInfoNV& input, uint64_t dst,
               uint64_t addresses, uint64_t sizes, uint64_t infos, uint64_t info_stride,
               std::vector<fbs::MemorySnapshot> inputs) {
        const uint64_t n = input.maxAccelerationStructureCount;
        auto info = tb::cluster_commands(input);
        info.dstImplicitData = dst;
        info.scratchData = scratch_address_;
        info.dstAddressesArray = {addresses, 8, n * 8};
        info.dstSizesArray = {sizes, 4, n * 4};
        info.srcInfosArray = {infos, info_stride, n * info_stride};
        fbs::CmdBuildClusterAccelerationStructureIndirectT b =
            tb::cluster_build(command_buffer_, info);
        b.inputs = std::move(inputs);
        append(record(std::move(b)));
        stats_.ops += n;
        stats_.cluster_ops += n;
        ++stats_.commands;
    }

    void wait_fence(uint64_t fence) {
        append(record(tb::fence_wait(fence)));
        fbs::FenceResetT reset;
        reset.fences.push_back(fence);
        append(record(std::move(reset)));
    }

    void write_frame(uint64_t frame) {
        const uint32_t s = uint32_t(frame % kSlots);
        const Slot& slot = slots_[s];
        const uint32_t k = shape_.clusters_per_build, per_frame = k * shape_.builds_per_frame;
        if (frame >= kSlots) wait_fence(kFence0 + s);
        if (frame > 0 && frame % kStreamEvery == 0) {
            // Streaming: the other frame in flight may still move into the old buffer.
            wait_fence(kFence0 + (s + 1) % kSlots);
            fbs::BufferDestroyT d;
            d.buffer = stream_buffer_;
            append(record(d));
            ++stats_.buffers_destroyed;
            stream_address_ = stream_at_;
            stream_buffer_ = add_buffer(stream_address_, stream_bytes_, kStorage, kDeviceMemory);
            stream_at_ += align_up(stream_bytes_, 0x100000);
        }
        submission_bytes_ = 0;
        command_buffer_ = kCommandBuffer0 + s;
        append(record(tb::command_buffer_begin(command_buffer_)));

        // Last frame's builds (same queue) may still use the scratch and this slot's buffers.
        barrier(kBuild | kTransfer, kAsWrite | VK_ACCESS_2_TRANSFER_WRITE_BIT, kBuild | kTransfer,
                kBuildReads | kAsWrite | VK_ACCESS_2_TRANSFER_WRITE_BIT |
                    VK_ACCESS_2_TRANSFER_READ_BIT);

        // The frame's cluster infos: picked from the pool, uploaded from staging.
        std::vector<Info> infos(per_frame);
        std::uniform_int_distribution<uint32_t> pick(0, shape_.cluster_pool - 1);
        std::vector<uint32_t> picked(per_frame);
        for (uint32_t i = 0; i < per_frame; ++i) {
            picked[i] = pick(rng_);
            const ClusterGeometry& g = geometry_[picked[i]];
            infos[i] =
                tb::triangle_cluster_info(uint32_t(frame * per_frame + i) & 0xFFFFFFu, g.triangles,
                                          g.vertices, index_address_ + g.index_offset, 1,
                                          vertex_address_ + g.vertex_offset);
        }
        const uint64_t info_bytes = per_frame * sizeof(Info);
        fbs::CmdCopyBufferT copy;
        copy.command_buffer = command_buffer_;
        copy.version = 1;
        copy.src_buffer = staging_buffer_;
        copy.dst_buffer = slot.infos_buffer;
        copy.regions.emplace_back(s * info_bytes, 0, info_bytes);
        copy.inputs.push_back(
            snapshot(staging_address_ + s * info_bytes, infos.data(), info_bytes));
        append(record(std::move(copy)));
        ++stats_.ops;
        ++stats_.commands;

        BlasInfo blas{};
        blas.clusterReferencesCount = per_frame;
        blas.clusterReferencesStride = 8;
        blas.clusterReferences = slot.addresses;
        fbs::CmdUpdateBufferT update;
        update.command_buffer = command_buffer_;
        update.dst_buffer = slot.infos_buffer;
        update.dst_offset = info_bytes;
        const auto* blas_bytes = reinterpret_cast<const uint8_t*>(&blas);
        update.data.assign(blas_bytes, blas_bytes + sizeof blas);
        append(record(std::move(update)));
        ++stats_.ops;
        ++stats_.commands;

        fbs::CmdFillBufferT fill;
        fill.command_buffer = command_buffer_;
        fill.dst_buffer = slot.sizes_buffer;
        fill.size = ~0ull;
        append(record(fill));
        ++stats_.ops;
        ++stats_.commands;

        barrier(kTransfer, VK_ACCESS_2_TRANSFER_WRITE_BIT, kBuild, kBuildReads | kAsWrite);

        for (uint32_t b = 0; b < shape_.builds_per_frame; ++b) {
            if (b > 0 && shape_.scratch_barriers)  // scratch reuse
                barrier(kBuild, kAsWrite, kBuild, kBuildReads | kAsWrite);
            const uint64_t first = uint64_t(b) * k;
            std::vector<fbs::MemorySnapshot> inputs;
            inputs.push_back(snapshot(slot.infos + first * sizeof(Info), infos.data() + first,
                                      k * sizeof(Info)));
            for (uint32_t i = 0; i < k; ++i) {
                const ClusterGeometry& g = geometry_[picked[first + i]];
                inputs.push_back(snapshot(vertex_address_ + g.vertex_offset,
                                          vertices_.data() + g.vertex_offset / 4,
                                          g.vertices * 12ull));
                inputs.push_back(snapshot(index_address_ + g.index_offset,
                                          indices_.data() + g.index_offset, g.triangles * 3ull));
            }
            build(clas_input(k), slot.clas + b * clas_bytes_, slot.addresses + first * 8,
                  slot.sizes + first * 4, slot.infos + first * sizeof(Info), sizeof(Info),
                  std::move(inputs));
        }

        barrier(kBuild, kAsWrite, kBuild, kBuildReads | kAsWrite);
        {
            std::vector<fbs::MemorySnapshot> inputs;
            inputs.push_back(snapshot(slot.infos + info_bytes, &blas, sizeof blas));
            build(blas_input(), slot.blas, slot.addresses + per_frame * 8,
                  slot.sizes + per_frame * 4, slot.infos + info_bytes, sizeof blas,
                  std::move(inputs));
        }
        if (frame % kMoveEvery == kMoveEvery - 1) {
            // Compaction: the first batch's clusters move into the streamed buffer.
            barrier(kBuild, kAsWrite, kBuild, kBuildReads | kAsWrite);
            build(move_input(k), stream_address_ + s * (stream_bytes_ / kSlots),
                  slot.addresses + (per_frame + 1) * 8, slot.sizes + (per_frame + 1) * 4,
                  slot.addresses, 8, {});
        }

        append(record(tb::command_buffer_end(command_buffer_)));
        append(record(tb::queue_submit(kQueue, {command_buffer_}, kFence0 + s,
                                       writer_.next_submission_index())));
        ++stats_.submissions;
        stats_.largest_submission_bytes =
            std::max(stats_.largest_submission_bytes, submission_bytes_);
    }

    struct Slot {
        uint64_t infos = 0, clas = 0, addresses = 0, sizes = 0, blas = 0;
        uint64_t infos_buffer = 0, clas_buffer = 0, addresses_buffer = 0, sizes_buffer = 0,
                 blas_buffer = 0;
    };

    BenchTraceShape shape_;
    std::mt19937_64 rng_;
    tb::RecordWriter writer_;
    BenchTraceStats stats_;
    std::vector<float> vertices_;
    std::vector<uint8_t> indices_;
    std::vector<ClusterGeometry> geometry_;
    VkClusterAccelerationStructureTriangleClusterInputNV tri_{};
    VkClusterAccelerationStructureClustersBottomLevelInputNV blas_in_{};
    VkClusterAccelerationStructureMoveObjectsInputNV move_in_{};
    uint64_t clas_bytes_ = 0, blas_bytes_ = 0, stream_bytes_ = 0;
    uint64_t vertex_address_ = 0, index_address_ = 0, scratch_address_ = 0, staging_address_ = 0;
    uint64_t vertex_buffer_ = 0, index_buffer_ = 0, scratch_buffer_ = 0, staging_buffer_ = 0;
    uint64_t stream_address_ = 0, stream_at_ = 0, stream_buffer_ = 0;
    Slot slots_[kSlots];
    uint64_t next_buffer_ = 0xb000;
    uint64_t command_buffer_ = kCommandBuffer0;
    uint64_t submission_bytes_ = 0;
};

}  // namespace

BenchTraceStats write_bench_trace(const std::string& path, const BenchTraceShape& shape) {
    Writer w(path, shape);
    BenchTraceStats stats = w.run();
    FILE* f = std::fopen(path.c_str(), "rb");
    if (f) {
        std::fseek(f, 0, SEEK_END);
        stats.file_bytes = uint64_t(std::ftell(f));
        std::fclose(f);
    }
    return stats;
}

}  // namespace clastrace::bench
