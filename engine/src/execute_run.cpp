// SPDX-License-Identifier: Apache-2.0
// Running the ops, chunk by chunk: every op of a chunk reads in parallel into its own
// buffer (execute_ops.cpp), then the chunk's writes land on one thread in op order.
#include "clastrace/engine/build_sizes.h"
#include "execute_command.h"

#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cstring>
#include <span>

namespace clastrace::engine::detail {

namespace {

// Objects a chunk wrote, by destination, for the directory.
using BuiltObjects = std::vector<std::pair<uint64_t, const OpOutput*>>;

// The op outputs of the commands a thread runs, kept from one command to the next: their object
// bytes and access lists keep their capacity, so a steady replay allocates neither per op. A
// command started while the thread waits inside another's ops (TBB may run one there) gets
// outputs of its own. What a thread keeps is bounded: kKeptOutputs outputs, each with at most a
// CLAS's or template's bytes (a bottom level's are let go) and kKeptAccesses accesses.
class KeptOpOutputs {
public:
    static constexpr size_t kKeptOutputs = 256;
    static constexpr size_t kKeptObjectBytes = size_t{16} << 10;  // > kMaxObjectBytes
    static constexpr size_t kKeptAccesses = 64;

    KeptOpOutputs() : pool_(in_use_ ? own_ : pool()) { in_use_ = true; }
    ~KeptOpOutputs() {
        trim();
        if (&pool_ == &pool()) in_use_ = false;
    }
    KeptOpOutputs(const KeptOpOutputs&) = delete;
    KeptOpOutputs& operator=(const KeptOpOutputs&) = delete;

    // n outputs as fresh as OpOutput{} but for their vectors' capacity.
    std::span<OpOutput> take(uint32_t n) {
        if (pool_.size() < n) pool_.resize(n);
        for (uint32_t k = 0; k < n; ++k) reset(pool_[k]);
        used_ = std::max<size_t>(used_, n);
        return {pool_.data(), n};
    }

private:
    static std::vector<OpOutput>& pool() {
        thread_local std::vector<OpOutput> outputs;
        return outputs;
    }
    static void reset(OpOutput& out) {
        std::vector<MemoryAccess> accesses = std::move(out.rec.accesses);
        std::vector<Finding> findings = std::move(out.rec.findings);
        std::vector<std::byte> bytes = std::move(out.bytes);
        accesses.clear();
        findings.clear();
        bytes.clear();
        out = OpOutput{};
        out.rec.accesses = std::move(accesses);
        out.rec.findings = std::move(findings);
        out.bytes = std::move(bytes);
    }
    void trim() {
        if (pool_.size() > kKeptOutputs) pool_.resize(kKeptOutputs);
        for (size_t k = 0; k < std::min(used_, pool_.size()); ++k) {
            OpOutput& out = pool_[k];
            if (out.bytes.capacity() > kKeptObjectBytes) std::vector<std::byte>().swap(out.bytes);
            if (out.rec.accesses.capacity() > kKeptAccesses)
                std::vector<MemoryAccess>().swap(out.rec.accesses);
        }
    }

    static thread_local bool in_use_;
    std::vector<OpOutput> own_;
    std::vector<OpOutput>& pool_;
    size_t used_ = 0;
};
thread_local bool KeptOpOutputs::in_use_ = false;

VkClusterAccelerationStructureTypeNV result_type(const OpOutput& out) {
    if (!out.is_object) return VK_CLUSTER_ACCELERATION_STRUCTURE_TYPE_MAX_ENUM_NV;
    return VkClusterAccelerationStructureTypeNV(out.type == ObjectType::kClustersBottomLevel ? 0
                                                : out.type == ObjectType::kTriangleCluster   ? 1
                                                                                             : 2);
}

// The bytes an implicit destination's object of `size` bytes takes (ExecuteOptions).
uint64_t implicit_room(const CommandState& s, uint64_t size) {
    return std::max(size, s.options.implicit_object_room);
}

// Where op i's object goes: the next aligned offset of the implicit data, or
// dstAddressesArray[i]. 0: nowhere (failed op, compute-sizes, or a wrapped address, whose
// write then faults).
uint64_t place_object(CommandState& s, OpOutput& out, uint32_t i, uint64_t size) {
    if (!out.ok) return 0;
    if (s.implicit) {
        uint64_t offset = align_up_sat(s.cursor, s.align);
        uint64_t dst = s.cmd.implicit_data + offset;
        s.cursor = sat_add(offset, implicit_room(s, size));
        return dst < s.cmd.implicit_data ? 0 : dst;
    }
    if (!s.explicit_mode) return 0;
    const uint64_t dst = out.explicit_dst;
    if (dst % s.align != 0)
        out.rec.finding(kRuleDestinationMisaligned,
                        "dstAddressesArray[" + std::to_string(i) + "] = " + hex(dst) +
                            " is not a multiple of the " + std::to_string(s.align) +
                            "-byte object alignment",
                        dst);
    return dst;
}

void write_object(CommandState& s, OpOutput& out, uint32_t i, uint64_t dst, OpResult& result,
                  BuiltObjects& built) {
    // An implicit object given more room than its bytes (ExecuteOptions::implicit_object_room)
    // zero-fills the rest: the command then defines every byte of the room, so a capture's
    // output snapshot of it replays without the memory's older contents.
    const uint64_t size = s.implicit ? implicit_room(s, out.bytes.size()) : out.bytes.size();
    FieldName where(s.implicit ? "dstImplicitData[op " : "*dstAddressesArray[");
    where.append_number(i).append("]");
    try {
        auto span = s.memory.write_bytes(dst, size, {where.c_str(), i});
        std::fill(std::copy(out.bytes.begin(), out.bytes.end(), span.begin()), span.end(),
                  std::byte{0});
        out.rec.access(dst, size, kAccessObjectWrite, true, std::move(where));
        result.dst_address = dst;
        s.written.push_back({dst, dst + size, i});
        built.push_back({dst, &out});
    } catch (const MemoryFault& fault) {
        out.rec.fault(fault);
        result.executed = false;
    }
}

// dstAddressesArray[i] (implicit mode) and dstSizesArray[i] (implicit and compute-sizes).
void write_result_arrays(CommandState& s, OpOutput& out, uint32_t i, uint64_t size,
                         const OpResult& result) {
    const ResolvedCommand& cmd = s.cmd;
    try {
        if (s.implicit && cmd.dst_addresses.deviceAddress != 0) {
            FieldName f("dstAddressesArray[");
            f.append_number(i).append("]");
            uint64_t a = MemoryImage::strided_address(cmd.dst_addresses, i, 8, {f.c_str(), i});
            s.memory.write<uint64_t>(a, result.dst_address, {f.c_str(), i});
            out.rec.access(a, 8, kAccessObjectWrite, true, f);
        }
        if ((s.implicit || s.sizes_only) && cmd.dst_sizes.deviceAddress != 0) {
            FieldName f("dstSizesArray[");
            f.append_number(i).append("]");
            uint64_t a = MemoryImage::strided_address(cmd.dst_sizes, i, 4, {f.c_str(), i});
            const uint64_t taken = s.implicit ? implicit_room(s, size) : size;
            uint32_t written_size =
                result.executed || (s.sizes_only && out.ok) ? uint32_t(taken) : 0;
            s.memory.write<uint32_t>(a, written_size, {f.c_str(), i});
            out.rec.access(a, 4, kAccessObjectWrite, true, f);
        }
    } catch (const MemoryFault& fault) {
        out.rec.fault(fault);
    }
}

// The engine's 16-byte (offset, size) entry of op i; a fault stops further entries.
void write_scratch_entry(CommandState& s, Recorder& rec, uint32_t i, uint64_t dst, uint64_t size) {
    if (!s.scratch_usable || s.cmd.scratch == 0) return;
    uint64_t entry[2] = {dst == 0 ? 0 : dst - (s.implicit ? s.cmd.implicit_data : 0), size};
    try {
        std::memcpy(
            s.memory.write_bytes(s.cmd.scratch + uint64_t(i) * 16, 16, {"scratchData", i}).data(),
            entry, 16);
    } catch (const MemoryFault& fault) {
        rec.fault(fault);
        s.scratch_usable = false;
    }
}

// The write phase of op i.
void write_op(CommandState& s, OpOutput& out, uint32_t i, BuiltObjects& built) {
    OpResult& result = s.record.ops[i];
    const uint64_t size = out.ok ? out.bytes.size() : 0;
    s.total_triangles += out.triangles;
    s.total_vertices += out.vertices;
    s.total_clusters += out.clusters;
    if (out.ok) {
        result.dst_size = size;
        result.executed = true;
        result.dst_type = result_type(out);
        if (s.is_move) {
            s.moved_bytes = sat_add(s.moved_bytes, size);
            s.move_sources.push_back({out.move_src, out.move_src + out.move_src_size, i});
        }
    }
    const uint64_t dst = place_object(s, out, i, size);
    if (out.ok && !s.sizes_only) write_object(s, out, i, dst, result, built);
    write_result_arrays(s, out, i, size, result);
    write_scratch_entry(s, out.rec, i, dst, size);
    for (auto& f : out.rec.findings) s.sink.add(std::move(f));
    out.rec.findings.clear();
}

// The chunk's accesses after the command's earlier ones, in op order, with one allocation.
void append_accesses(CommandState& s, std::span<OpOutput> outs) {
    size_t total = s.op_accesses.size();
    for (const OpOutput& out : outs) total += out.rec.accesses.size();
    s.op_accesses.reserve(total);
    for (OpOutput& out : outs)
        for (MemoryAccess& a : out.rec.accesses) s.op_accesses.push_back(std::move(a));
}

// Move sources retired first, so a swap (A->B, B->A) leaves both live.
void update_directory(CommandState& s, const BuiltObjects& built) {
    if (s.is_move && !s.input.opInput.pMoveObjects->noMoveOverlap)
        for (auto& [dst, out] : built) s.directory.record_moved_away(out->move_src, dst);
    for (auto& [dst, out] : built)
        if (out->is_object) s.directory.record_built(dst, out->type, out->bytes);
}

}  // namespace

void run_ops(CommandState& s) {
    const ResolvedCommand& cmd = s.cmd;
    const EngineProperties& props = s.options.properties;
    tbb::enumerable_thread_specific<ClusterBuilder> builders(
        [&props] { return ClusterBuilder(props); });
    KeptOpOutputs kept;
    s.written.reserve(cmd.count);
    BuiltObjects built;
    for (uint64_t base = 0; base < cmd.count; base += kOpsPerChunk) {
        const uint32_t n = uint32_t(std::min<uint64_t>(kOpsPerChunk, cmd.count - base));
        std::span<OpOutput> outs = kept.take(n);
        tbb::parallel_for(uint32_t(0), n, [&](uint32_t k) {
            run_op(cmd, s.memory, uint32_t(base + k), builders.local(), outs[k]);
        });
        built.clear();
        built.reserve(n);
        for (uint32_t k = 0; k < n; ++k) write_op(s, outs[k], uint32_t(base + k), built);
        append_accesses(s, outs);
        update_directory(s, built);
    }
    s.record.implicit_bytes_used = s.implicit ? s.cursor : 0;
    if (cmd.scratch != 0 && cmd.count > 0) {
        s.record.scratch_bytes_used = scratch_bytes_for_ops(cmd.count);
        s.top.access(cmd.scratch, s.record.scratch_bytes_used, kAccessScratch, true, "scratchData");
    }
}

}  // namespace clastrace::engine::detail
