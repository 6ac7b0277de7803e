// SPDX-License-Identifier: Apache-2.0
#include "command_events.h"

#include <algorithm>
#include <cstring>
#include <optional>
#include <string_view>

#include <fmt/format.h>

#include <clastrace/common/enum_bits.h>
#include <clastrace/engine/cluster_format.h>
#include <clastrace/engine/execution_record.h>
#include <clastrace/engine/memory_image.h>

namespace clastrace::analyze::detail {

namespace {

using engine::ExecutionRecord;
using engine::MemoryAccess;

bool build_object(engine::ClusterBuilder& builder, const engine::MemoryImage& memory,
                  const VkClusterAccelerationStructureBuildTriangleClusterInfoNV& info,
                  const VkClusterAccelerationStructureTriangleClusterInputNV& input,
                  int64_t op_index, std::vector<std::byte>& out,
                  std::vector<engine::Finding>& findings) {
    return builder.build_triangle_cluster(memory, info, input, op_index, out, findings);
}
bool build_object(engine::ClusterBuilder& builder, const engine::MemoryImage& memory,
                  const VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV& info,
                  const VkClusterAccelerationStructureTriangleClusterInputNV& input,
                  int64_t op_index, std::vector<std::byte>& out,
                  std::vector<engine::Finding>& findings) {
    return builder.build_triangle_cluster_template(memory, info, input, op_index, out, findings);
}

// One id per (role, range): a later command using the same bytes in the same role extends
// that region's lifetime; the same bytes in another role are another region.
uint64_t region_id(RegionRole role, uint64_t base, uint64_t size) {
    auto mix = [](uint64_t x) {  // splitmix64 finalizer
        x ^= x >> 30;
        x *= 0xbf58476d1ce4e5b9ull;
        x ^= x >> 27;
        x *= 0x94d049bb133111ebull;
        return x ^ (x >> 31);
    };
    return mix(mix(mix(static_cast<uint64_t>(role) + 1) ^ base) ^ size);
}

RegionInfo region(RegionRole role, uint64_t base, uint64_t size, bool written, std::string label) {
    return RegionInfo{region_id(role, base, size), std::move(label), base, size, role, written};
}

RegionRole object_role(VkClusterAccelerationStructureTypeNV type) {
    switch (type) {
    case VK_CLUSTER_ACCELERATION_STRUCTURE_TYPE_TRIANGLE_CLUSTER_NV: return RegionRole::kObjectClas;
    case VK_CLUSTER_ACCELERATION_STRUCTURE_TYPE_TRIANGLE_CLUSTER_TEMPLATE_NV:
        return RegionRole::kObjectTemplate;
    case VK_CLUSTER_ACCELERATION_STRUCTURE_TYPE_CLUSTERS_BOTTOM_LEVEL_NV:
        return RegionRole::kObjectBlas;
    default: return RegionRole::kOther;
    }
}

ObjectType object_type(VkClusterAccelerationStructureTypeNV type) {
    switch (type) {
    case VK_CLUSTER_ACCELERATION_STRUCTURE_TYPE_TRIANGLE_CLUSTER_NV: return ObjectType::kClas;
    case VK_CLUSTER_ACCELERATION_STRUCTURE_TYPE_TRIANGLE_CLUSTER_TEMPLATE_NV:
        return ObjectType::kClusterTemplate;
    case VK_CLUSTER_ACCELERATION_STRUCTURE_TYPE_CLUSTERS_BOTTOM_LEVEL_NV: return ObjectType::kBlas;
    default: return ObjectType::kOther;
    }
}

bool starts_with(std::string_view s, std::string_view p) { return s.substr(0, p.size()) == p; }
bool contains(std::string_view s, std::string_view p) {
    return s.find(p) != std::string_view::npos;
}

// The role of an engine access, from the field the engine names (execution_record.h).
// Objects are not classified here: they come from the per-op results.
RegionRole access_role(const MemoryAccess& a) {
    std::string_view f = a.field;
    if (f == "scratchData") return RegionRole::kScratch;
    if (starts_with(f, "dstAddressesArray")) return RegionRole::kDstAddresses;
    if (starts_with(f, "dstSizesArray")) return RegionRole::kDstSizes;
    if (f == "srcInfosCount") return RegionRole::kSrcInfosCount;
    if (starts_with(f, "srcInfosArray[")) {
        if (f.back() == ']' && !contains(f, ".")) return RegionRole::kSrcInfos;
        if (contains(f, ".vertexBuffer")) return RegionRole::kVertex;
        if (contains(f, ".indexBuffer") && !contains(f, "opacityMicromap"))
            return RegionRole::kIndex;
        if (contains(f, "clusterReferences[*]")) return RegionRole::kObjectClas;
        if (contains(f, ".clusterTemplateAddress") &&
            (a.access & VK_ACCESS_2_ACCELERATION_STRUCTURE_READ_BIT_KHR))
            return RegionRole::kObjectTemplate;
    }
    return RegionRole::kOther;
}

const char* role_label(RegionRole r) {
    switch (r) {
    case RegionRole::kScratch: return "scratch";
    case RegionRole::kImplicitData: return "implicit data";
    case RegionRole::kDstAddresses: return "dstAddressesArray";
    case RegionRole::kDstSizes: return "dstSizesArray";
    case RegionRole::kSrcInfos: return "srcInfosArray";
    case RegionRole::kSrcInfosCount: return "srcInfosCount";
    case RegionRole::kObjectClas: return "CLAS";
    case RegionRole::kObjectTemplate: return "template";
    case RegionRole::kObjectBlas: return "BLAS";
    case RegionRole::kVertex: return "vertices";
    case RegionRole::kIndex: return "indices";
    default: return "other";
    }
}

struct Span {
    uint64_t begin, end;
    bool written;
};

// Non-object accesses of one role merged into the ranges they cover.
void add_merged(std::vector<Span>& spans, RegionRole role, std::vector<RegionInfo>& out) {
    std::sort(spans.begin(), spans.end(),
              [](const Span& a, const Span& b) { return a.begin < b.begin; });
    for (std::size_t i = 0; i < spans.size();) {
        Span m = spans[i++];
        while (i < spans.size() && spans[i].begin <= m.end) {
            m.end = std::max(m.end, spans[i].end);
            m.written = m.written || spans[i].written;
            ++i;
        }
        out.push_back(region(role, m.begin, m.end - m.begin, m.written,
                             fmt::format("{} 0x{:x}", role_label(role), m.begin)));
    }
}

// The VkBuffers holding the command's regions (role buffer: drawn, never an overlap).
void add_buffers(const RecordedState& recorded, std::vector<RegionInfo>& regions) {
    std::vector<RecordedState::Buffer> seen;
    for (std::size_t i = 0, n = regions.size(); i < n; ++i) {
        auto b = recorded.buffer_at(regions[i].base);
        if (!b || std::any_of(seen.begin(), seen.end(),
                              [&](const auto& s) { return s.handle == b->handle; }))
            continue;
        seen.push_back(*b);
        regions.push_back(region(RegionRole::kBuffer, b->base, b->size, false,
                                 fmt::format("VkBuffer 0x{:x}", b->handle)));
    }
}

// Bytes from `address` to the end of its buffer: what the application made available.
std::optional<uint64_t> available(const RecordedState& recorded, uint64_t address) {
    if (address == 0) return std::nullopt;
    auto b = recorded.buffer_at(address);
    if (!b) return std::nullopt;
    return b->base + b->size - address;
}

// The header of the engine object at `address` in replay memory, if one is there.
std::optional<engine::ObjectHeader> engine_object_header(const engine::MemoryImage* memory,
                                                         uint64_t address) {
    if (!memory || address == 0) return std::nullopt;
    try {
        const auto bytes = memory->read_bytes(address, sizeof(engine::ObjectHeader),
                                              engine::FieldRef{"object header", -1});
        engine::ObjectHeader h;
        std::memcpy(&h, bytes.data(), sizeof h);
        if (h.magic != engine::kObjectMagic) return std::nullopt;
        return h;
    } catch (const engine::MemoryFault&) {
        return std::nullopt;
    }
}

VkClusterAccelerationStructureTriangleClusterInputNV triangle_input(
    const fbs::ClusterInputInfo* in) {
    VkClusterAccelerationStructureTriangleClusterInputNV t{};
    t.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_TRIANGLE_CLUSTER_INPUT_NV;
    if (const auto* f = in ? in->op_input_as_TriangleClusterInput() : nullptr) {
        common::set_enum_bits(t.vertexFormat, f->vertex_format());
        t.maxGeometryIndexValue = f->max_geometry_index_value();
        t.maxClusterUniqueGeometryCount = f->max_cluster_unique_geometry_count();
        t.maxClusterTriangleCount = f->max_cluster_triangle_count();
        t.maxClusterVertexCount = f->max_cluster_vertex_count();
        t.maxTotalTriangleCount = f->max_total_triangle_count();
        t.maxTotalVertexCount = f->max_total_vertex_count();
        t.minPositionTruncateBitCount = f->min_position_truncate_bit_count();
    }
    return t;
}

template <class T>
std::optional<T> read_info(const engine::MemoryImage* memory, uint64_t address) {
    if (!memory || address == 0) return std::nullopt;
    try {
        return memory->read<T>(address, {"srcInfosArray", -1});
    } catch (const engine::MemoryFault&) {
        return std::nullopt;
    }
}

// The captured dstSizesArray values (the driver's sizes), where the capture recorded them.
class CapturedSizes {
public:
    // Explicit mode reads dstSizesArray (the application's sizes): nothing captured to compare.
    CapturedSizes(const fbs::CmdBuildClusterAccelerationStructureIndirect& b,
                  const DescribeContext& c, bool written) {
        const auto* sizes = b.dst_sizes_array();
        if (!written || !sizes || sizes->device_address() == 0 || !b.outputs() || !c.contents)
            return;
        if (b.address_resolution_flags() &
            VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_DST_SIZES_ARRAY_BIT_NV)
            return;
        for (const fbs::MemorySnapshot* s : *b.outputs()) {
            if (s->address() != 0 && s->address() <= sizes->device_address() &&
                sizes->device_address() - s->address() < s->size() &&
                c.contents(s->hash(), &bytes_)) {
                base_ = s->address();
                stride_ = sizes->stride() ? sizes->stride() : 4;
                first_ = sizes->device_address();
                return;
            }
        }
        bytes_.clear();
    }
    std::optional<uint32_t> at(uint64_t op) const {
        if (bytes_.empty() || op > (UINT64_MAX - first_) / stride_) return std::nullopt;
        const uint64_t offset = first_ + op * stride_ - base_;
        if (offset > bytes_.size() || bytes_.size() - offset < 4) return std::nullopt;
        uint32_t v;
        std::memcpy(&v, bytes_.data() + offset, 4);
        return v;
    }

private:
    std::vector<uint8_t> bytes_;
    uint64_t base_ = 0, stride_ = 4, first_ = 0;
};

// The command's memory regions: engine accesses by role (merged), the objects a move reads and
// the CLAS/template objects it touches one by one, and the implicit data it used. Returns each
// op's srcInfosArray entry address (0 where the engine read none).
std::vector<uint64_t> add_cluster_regions(
    const ExecutionRecord& e, const fbs::CmdBuildClusterAccelerationStructureIndirect& b,
    bool implicit, std::vector<RegionInfo>& regions) {
    const fbs::ClusterInputInfo* input = b.input();
    std::vector<std::vector<Span>> by_role(kRegionRoleCount);
    std::vector<uint64_t> info_address(e.ops.size(), 0);
    for (const MemoryAccess& a : e.accesses) {
        if (a.end <= a.begin) continue;
        const RegionRole role = access_role(a);
        if (role == RegionRole::kSrcInfos && a.op_index >= 0 &&
            static_cast<uint64_t>(a.op_index) < info_address.size())
            info_address[a.op_index] = a.begin;
        if (starts_with(a.field, "dstImplicitData[op ") ||
            starts_with(a.field, "*dstAddressesArray["))
            continue;  // objects
        if (contains(a.field, ".srcAccelerationStructure") &&
            !a.is_write) {  // a move's source object
            const auto* move = input ? input->op_input_as_MoveObjectsInput() : nullptr;
            const RegionRole source =
                move ? object_role(static_cast<VkClusterAccelerationStructureTypeNV>(move->type()))
                     : RegionRole::kOther;
            regions.push_back(region(source, a.begin, a.end - a.begin, false,
                                     fmt::format("{} 0x{:x}", role_label(source), a.begin)));
            continue;
        }
        if (role == RegionRole::kObjectClas || role == RegionRole::kObjectTemplate) {
            regions.push_back(region(role, a.begin, a.end - a.begin, a.is_write,
                                     fmt::format("{} 0x{:x}", role_label(role), a.begin)));
            continue;
        }
        by_role[static_cast<int>(role)].push_back(Span{a.begin, a.end, a.is_write});
    }
    if (implicit && e.implicit_bytes_used && b.dst_implicit_data())
        regions.push_back(region(RegionRole::kImplicitData, b.dst_implicit_data(),
                                 e.implicit_bytes_used, true,
                                 fmt::format("implicit data 0x{:x}", b.dst_implicit_data())));
    for (int r = 0; r < kRegionRoleCount; ++r)
        if (!by_role[r].empty()) add_merged(by_role[r], static_cast<RegionRole>(r), regions);
    return info_address;
}

// What one cluster command's objects hold (triangles, vertices, truncation), read from their
// srcInfosArray entries in replay memory, or for an instantiation from its template's shape.
class ClusterObjectShapes {
public:
    ClusterObjectShapes(DescribeContext& ctx, const engine::MemoryImage* memory, OpType op_type,
                        const fbs::ClusterInputInfo* input)
        : ctx_(ctx),
          memory_(memory),
          op_type_(op_type),
          input_(triangle_input(input)),
          budget_(ctx.rebuild_budget) {}

    void read(const engine::OpResult& op, std::size_t op_index, uint64_t info_address,
              ObjectInfo& o) {
        const auto i64 = static_cast<int64_t>(op_index);
        if (op_type_ == OpType::kBuildTriangleCluster) {
            if (auto t = read_info<VkClusterAccelerationStructureBuildTriangleClusterInfoNV>(
                    memory_, info_address)) {
                o.triangles = t->triangleCount;
                o.vertices = t->vertexCount;
                o.truncate_bits = t->positionTruncateBitCount;
                rebuild_untruncated(*t, i64, o);
            }
        } else if (op_type_ == OpType::kBuildTriangleClusterTemplate) {
            if (auto t =
                    read_info<VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV>(
                        memory_, info_address)) {
                o.triangles = t->triangleCount;
                o.vertices = t->vertexCount;
                o.truncate_bits = t->positionTruncateBitCount;
                if (op.dst_address && ctx_.templates.size() < (1u << 16))
                    ctx_.templates[op.dst_address] = TemplateShape{t->triangleCount, t->vertexCount,
                                                                   t->positionTruncateBitCount};
                rebuild_untruncated(*t, i64, o);
            }
        } else if (op_type_ == OpType::kInstantiateTriangleCluster) {
            if (auto t =
                    read_info<VkClusterAccelerationStructureInstantiateClusterInfoNV>(memory_,
                                                                                      info_address))
                read_instantiated(*t, op.dst_address, o);
        }
    }

private:
    void read_instantiated(const VkClusterAccelerationStructureInstantiateClusterInfoNV& t,
                           uint64_t dst_address, ObjectInfo& o) const {
        auto shape = ctx_.templates.find(t.clusterTemplateAddress);
        if (shape != ctx_.templates.end()) {
            o.triangles = shape->second.triangles;
            o.vertices = shape->second.vertices;
            o.truncate_bits = shape->second.truncate_bits;
        } else if (auto h = engine_object_header(memory_, dst_address)) {
            // A template moved (or built before the trace) is not in ctx.templates: the
            // instantiated object's own header says what it holds.
            o.triangles = h->triangle_count;
            o.vertices = h->vertex_count;
            o.truncate_bits = h->position_truncate_bits;
        }
    }

    // A truncated object is built again at positionTruncateBitCount 0 while the command's
    // budget lasts, so that what truncation saved is measured, not estimated.
    template <class Info>
    void rebuild_untruncated(Info at_zero, int64_t op_index, ObjectInfo& o) {
        if (o.truncate_bits == 0 || budget_ == 0 || !memory_) return;
        --budget_;
        at_zero.positionTruncateBitCount = 0;
        auto in_zero = input_;
        in_zero.minPositionTruncateBitCount = 0;
        ignored_.clear();
        if (build_object(ctx_.builder, *memory_, at_zero, in_zero, op_index, rebuilt_, ignored_))
            o.engine_bytes_untruncated = rebuilt_.size();
        ++ctx_.rebuilds;
    }

    DescribeContext& ctx_;
    const engine::MemoryImage* memory_;
    OpType op_type_;
    VkClusterAccelerationStructureTriangleClusterInputNV input_;
    uint32_t budget_;
    std::vector<std::byte> rebuilt_;
    std::vector<engine::Finding> ignored_;
};

void describe_cluster(const replay::ReplayedCommand& c,
                      const fbs::CmdBuildClusterAccelerationStructureIndirect& b,
                      DescribeContext& ctx, HeldCommand* out) {
    CommandInfo& info = out->info;
    const fbs::ClusterInputInfo* input = b.input();
    const uint32_t vk_type = input ? input->op_type() : 0xffu,
                   vk_mode = input ? input->op_mode() : 0xffu;
    info.op_type = vk_type < static_cast<uint32_t>(OpType::kOther) ? static_cast<OpType>(vk_type)
                                                                   : OpType::kOther;
    info.op_mode = vk_mode < static_cast<uint32_t>(OpMode::kNone) ? static_cast<OpMode>(vk_mode)
                                                                  : OpMode::kNone;
    if (input) out->query = ctx.recorded.query_for(*input);
    const ExecutionRecord* e = c.execution;
    if (!e) return;  // outside the selection, or the engine stopped: counted, nothing measured
    info.op_count = e->ops.size();
    info.replay_ns = c.engine_ns;
    if (e->scratch_address) info.scratch_used_bytes = e->scratch_bytes_used;
    info.scratch_allocated_bytes =
        available(ctx.recorded, e->scratch_address ? e->scratch_address : b.scratch_data());
    const bool implicit = info.op_mode == OpMode::kImplicitDestinations;
    if (implicit) {
        info.implicit_allocated_bytes = available(ctx.recorded, b.dst_implicit_data());
        info.implicit_used_bytes = e->implicit_bytes_used;
    }
    const std::vector<uint64_t> info_address = add_cluster_regions(*e, b, implicit, out->regions);

    // Objects one by one from the op results.
    const CapturedSizes captured(b, ctx, info.op_mode != OpMode::kExplicitDestinations);
    ClusterObjectShapes shapes(ctx, c.memory, info.op_type, input);
    for (std::size_t i = 0; i < e->ops.size(); ++i) {
        const engine::OpResult& op = e->ops[i];
        if (!op.executed) continue;
        const bool sizes_only = info.op_mode == OpMode::kComputeSizes;
        if (!sizes_only && op.dst_address == 0) continue;
        ObjectInfo o;
        o.op_index = static_cast<uint32_t>(i);
        o.type = object_type(op.dst_type);
        if (info.op_type == OpType::kGetClusterTemplateIndices) o.type = ObjectType::kOther;
        o.address = op.dst_address;
        o.engine_bytes = op.dst_size;
        if (auto d = captured.at(i)) o.driver_bytes = *d;
        shapes.read(op, i, info_address[i], o);
        info.triangles += o.triangles;
        if (!sizes_only && op.dst_size) {
            const RegionRole role = info.op_type == OpType::kGetClusterTemplateIndices
                                        ? RegionRole::kOther
                                        : object_role(op.dst_type);
            out->regions.push_back(
                region(role, op.dst_address, op.dst_size, true,
                       fmt::format("{} 0x{:x}", role_label(role), op.dst_address)));
        }
        out->objects.push_back(o);
    }
    add_buffers(ctx.recorded, out->regions);
}

uint64_t index_bytes(uint32_t index_type) {
    switch (index_type) {
    case VK_INDEX_TYPE_UINT16: return 2;
    case VK_INDEX_TYPE_UINT32: return 4;
    case VK_INDEX_TYPE_UINT8_EXT: return 1;
    default: return 0;  // VK_INDEX_TYPE_NONE_NV: no index buffer
    }
}

// vkCmdBuildAccelerationStructureNV: what its record says (replay of its objects comes from
// the engine where it runs them: then the execution record's ops are the objects).
void describe_nv_build(const replay::ReplayedCommand& c,
                       const fbs::CmdBuildAccelerationStructureNV& b, DescribeContext& ctx,
                       HeldCommand* out) {
    CommandInfo& info = out->info;
    const RecordedState& rec = ctx.recorded;
    if (const auto* i = b.info()) {
        if (i->geometries() && i->geometries()->size()) {
            info.op_count = i->geometries()->size();
            for (const fbs::GeometryNV* g : *i->geometries()) {
                const fbs::GeometryTrianglesNV* t = g->triangles();
                if (g->geometry_type() != VK_GEOMETRY_TYPE_TRIANGLES_NV || !t) continue;
                const uint64_t index_size = index_bytes(t->index_type());
                info.triangles += (index_size ? t->index_count() : t->vertex_count()) / 3;
                if (auto v = rec.buffer_address(t->vertex_data()); v && t->vertex_count())
                    out->regions.push_back(
                        region(RegionRole::kVertex, *v + t->vertex_offset(),
                               uint64_t{t->vertex_count()} *
                                   std::max<uint64_t>(t->vertex_stride(), 1),
                               false, fmt::format("vertices 0x{:x}", *v + t->vertex_offset())));
                if (auto x = rec.buffer_address(t->index_data());
                    x && index_size && t->index_count())
                    out->regions.push_back(
                        region(RegionRole::kIndex, *x + t->index_offset(),
                               uint64_t{t->index_count()} * index_size, false,
                               fmt::format("indices 0x{:x}", *x + t->index_offset())));
            }
        } else {
            info.op_count = i->instance_count();
        }
    }
    info.driver_object_bytes = rec.nv_object_bytes(b.dst());
    if (auto s = rec.buffer_address(b.scratch())) {
        const uint64_t base = *s + b.scratch_offset();
        const uint64_t need = rec.nv_build_scratch_bytes(b.dst());
        info.scratch_allocated_bytes = available(rec, base);
        if (need)
            out->regions.push_back(region(RegionRole::kScratch, base, need, true,
                                          fmt::format("scratch 0x{:x}", base)));
    }
    if (c.execution) {
        info.replay_ns = c.engine_ns ? c.engine_ns : c.replay_ns;
        for (std::size_t i = 0; i < c.execution->ops.size(); ++i) {
            const engine::OpResult& op = c.execution->ops[i];
            if (!op.executed || op.dst_size == 0) continue;
            ObjectInfo o;
            o.op_index = static_cast<uint32_t>(i);
            o.type = ObjectType::kBlas;
            o.address = op.dst_address;
            o.engine_bytes = op.dst_size;
            if (info.driver_object_bytes) o.driver_bytes = info.driver_object_bytes;
            o.triangles = info.triangles;
            out->objects.push_back(o);
        }
        // The driver's size now sits on the rebuilt objects: the command-level figure is only
        // for commands whose objects the replay does not rebuild.
        if (!out->objects.empty()) info.driver_object_bytes = 0;
    }
    add_buffers(rec, out->regions);
}

// vkCmdCopyMemoryToAccelerationStructureKHR: the serialized source and the destination object.
void describe_deserialize(const replay::ReplayedCommand& c,
                          const fbs::CmdCopyMemoryToAccelerationStructure& k, DescribeContext& ctx,
                          HeldCommand* out) {
    CommandInfo& info = out->info;
    info.op_count = 1;
    uint64_t src_size = 0;
    if (k.inputs())
        for (const fbs::MemorySnapshot* s : *k.inputs())
            if (s->address() == k.src_address()) src_size = std::max(src_size, s->size());
    if (src_size)
        out->regions.push_back(region(RegionRole::kOther, k.src_address(), src_size, false,
                                      fmt::format("serialized 0x{:x}", k.src_address())));
    if (const RecordedState::KhrObject* o = ctx.recorded.khr_object(k.dst())) {
        info.driver_object_bytes = o->size;
        if (auto base = ctx.recorded.buffer_address(o->buffer); base && o->size)
            out->regions.push_back(region(RegionRole::kObjectBlas, *base + o->offset, o->size, true,
                                          fmt::format("AS 0x{:x}", k.dst())));
    }
    if (c.execution) {
        info.replay_ns = c.engine_ns ? c.engine_ns : c.replay_ns;
        for (const engine::OpResult& op : c.execution->ops) {
            if (!op.executed || op.dst_size == 0) continue;
            ObjectInfo o;
            o.type = object_type(op.dst_type) == ObjectType::kOther ? ObjectType::kBlas
                                                                    : object_type(op.dst_type);
            o.address = op.dst_address;
            o.engine_bytes = op.dst_size;
            if (info.driver_object_bytes) o.driver_bytes = info.driver_object_bytes;
            out->objects.push_back(o);
        }
        if (!out->objects.empty()) info.driver_object_bytes = 0;  // on the objects now
    }
    add_buffers(ctx.recorded, out->regions);
}

}  // namespace

std::size_t HeldCommand::held_bytes() const {
    std::size_t n = sizeof(*this) + info.name.capacity() + regions.capacity() * sizeof(RegionInfo) +
                    objects.capacity() * sizeof(ObjectInfo) +
                    hazards.capacity() * sizeof(HazardSummary);
    for (const RegionInfo& r : regions) n += r.label.capacity() > 15 ? r.label.capacity() : 0;
    for (const HazardSummary& h : hazards) n += h.message.capacity() + h.hazard_class.capacity();
    return n;
}

void describe_command(const replay::ReplayedCommand& c, DescribeContext& ctx, HeldCommand* out) {
    const fbs::Record& r = *c.record;
    CommandInfo& info = out->info;
    info.ordinal = c.where.sequence;
    info.submission = c.where.submission;
    // A command of a secondary command buffer is listed under the secondary, at its index there.
    info.command_buffer =
        c.where.secondary_handle ? c.where.secondary_handle : c.where.command_buffer_handle;
    info.index = c.where.secondary_handle ? c.where.secondary_command : c.where.command;
    info.name = c.where.name ? c.where.name : "";
    out->command_buffer_index = c.where.command_buffer;
    switch (r.body_type()) {
    case fbs::RecordBody::GpuTimestamp: {
        out->kind = HeldCommand::Kind::kTimestamp;
        out->ticks = r.body_as_GpuTimestamp()->ticks();
        out->ticks_valid = r.body_as_GpuTimestamp()->ticks_valid();
        return;
    }
    case fbs::RecordBody::DebugLabel: out->kind = HeldCommand::Kind::kLabel; return;
    case fbs::RecordBody::CmdPipelineBarrier:
    case fbs::RecordBody::CmdSetEvent:
    case fbs::RecordBody::CmdResetEvent:
    case fbs::RecordBody::CmdWaitEvents: out->kind = HeldCommand::Kind::kSync; break;
    default: break;
    }
    // Replay time is engine time: set below for the commands the engine ran.
    switch (r.body_type()) {
    case fbs::RecordBody::CmdBuildClusterAccelerationStructureIndirect:
        describe_cluster(c, *r.body_as_CmdBuildClusterAccelerationStructureIndirect(), ctx, out);
        break;
    case fbs::RecordBody::CmdBuildAccelerationStructureNV:
        describe_nv_build(c, *r.body_as_CmdBuildAccelerationStructureNV(), ctx, out);
        break;
    case fbs::RecordBody::CmdCopyMemoryToAccelerationStructure:
        describe_deserialize(c, *r.body_as_CmdCopyMemoryToAccelerationStructure(), ctx, out);
        break;
    default: break;
    }
}

}  // namespace clastrace::analyze::detail
