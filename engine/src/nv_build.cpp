// SPDX-License-Identifier: Apache-2.0
// vkCmdBuildAccelerationStructureNV: command checks, input gathering (nv_gather.cpp),
// tree build or refit, and the write into dst's memory.
#include "clastrace/engine/nv_build.h"
#include "clastrace/common/hex.h"

#include "nv_gather.h"
#include "nv_internal.h"

#include <algorithm>
#include <cstring>
#include <functional>
#include <map>
#include <memory>

namespace clastrace::engine {
namespace nv {

void Context::finding(const char* rule, std::string message, uint64_t address) {
    uint32_t& n = per_rule[rule];
    if (++n > options.max_findings_per_rule) return;
    record.findings.push_back(Finding{rule, std::move(message), op_index, address});
}

void Context::access(uint64_t begin, uint64_t size, VkAccessFlags2 access, bool write,
                     std::string field) {
    if (size == 0) return;
    const uint64_t end = begin + size < begin ? ~0ull : begin + size;
    record.accesses.push_back(
        MemoryAccess{begin, end, kStageBuild, access, write, std::move(field), op_index});
}

void Context::close() {
    for (const auto& [rule, n] : per_rule)
        if (n > options.max_findings_per_rule)
            record.findings.push_back(Finding{kRuleNvFindingsTruncated,
                                              std::to_string(n - options.max_findings_per_rule) +
                                                  " more findings of " + rule +
                                                  " in this command were not listed",
                                              -1, 0});
}

}  // namespace nv

namespace {

using nv::Box;
using nv::Context;

uint64_t input_primitives(const NvGeometry& g) {
    if (g.type == VK_GEOMETRY_TYPE_AABBS_NV) return g.aabbs.count;
    return g.triangles.index_type == VK_INDEX_TYPE_NONE_NV ? g.triangles.vertex_count / 3
                                                           : g.triangles.index_count / 3;
}

bool overlaps(uint64_t a, uint64_t an, uint64_t b, uint64_t bn) {
    if (an == 0 || bn == 0) return false;
    const uint64_t ae = a + an < a ? ~0ull : a + an, be = b + bn < b ? ~0ull : b + bn;
    return a < be && b < ae;
}

using common::hex;

// Flags and counts of pInfo against each other and the limits. False when the build cannot run.
bool check_info_counts(Context& c) {
    const NvObjectInfo& info = c.command.info;
    const bool top = info.type == VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_NV;
    bool ok = true;
    if ((info.flags & VK_BUILD_ACCELERATION_STRUCTURE_PREFER_FAST_TRACE_BIT_NV) &&
        (info.flags & VK_BUILD_ACCELERATION_STRUCTURE_PREFER_FAST_BUILD_BIT_NV))
        c.finding(kVuidInfoFastBoth,
                  "pInfo->flags has both PREFER_FAST_TRACE and PREFER_FAST_BUILD");
    if (top && !info.geometries.empty()) {
        c.finding(kVuidInfoTopGeometries,
                  "top-level build with geometryCount " + std::to_string(info.geometries.size()));
        ok = false;
    }
    if (!top && info.instance_count != 0) {
        c.finding(kVuidInfoBottomInstances,
                  "bottom-level build with instanceCount " + std::to_string(info.instance_count));
        ok = false;
    }
    if (info.geometries.size() > c.options.limits.max_geometry_count) {
        c.finding(kVuidNvGeometryCount, "geometryCount " + std::to_string(info.geometries.size()) +
                                            " exceeds maxGeometryCount " +
                                            std::to_string(c.options.limits.max_geometry_count));
        ok = false;
    }
    if (top && info.instance_count > c.options.limits.max_instance_count) {
        c.finding(kVuidInfoInstanceCount, "instanceCount " + std::to_string(info.instance_count) +
                                              " exceeds maxInstanceCount " +
                                              std::to_string(c.options.limits.max_instance_count));
        ok = false;
    }
    uint64_t triangles = 0;
    for (size_t g = 0; g < info.geometries.size(); ++g) {
        if (info.geometries[g].type != info.geometries[0].type) {
            c.finding(kVuidInfoMixedTypes, "pGeometries[" + std::to_string(g) +
                                               "] has another geometryType than pGeometries[0]");
            ok = false;
            break;
        }
        if (info.geometries[g].type == VK_GEOMETRY_TYPE_TRIANGLES_NV)
            triangles += input_primitives(info.geometries[g]);
    }
    if (triangles > c.options.limits.max_triangle_count) {
        c.finding(kVuidInfoTriangleCount, "the geometries hold " + std::to_string(triangles) +
                                              " triangles, above maxTriangleCount " +
                                              std::to_string(c.options.limits.max_triangle_count));
        ok = false;
    }
    return ok;
}

// dst bound, and compatible with what it was created for.
bool check_dst(Context& c) {
    const NvBuildCommand& cmd = c.command;
    const NvObjectInfo& info = cmd.info;
    bool ok = true;
    if (cmd.dst.handle == 0 || !cmd.dst.bound) {
        c.finding(kVuidNvDstBound,
                  "dst " + hex(cmd.dst.handle) +
                      " has no memory bound (vkBindAccelerationStructureMemoryNV)");
        ok = false;
    }
    if (cmd.dst.created) {
        const NvObjectInfo& made = *cmd.dst.created;
        std::string why;
        if (made.type != info.type)
            why = "type differs from the type dst was created with";
        else if (made.flags != info.flags)
            why = "flags " + hex(info.flags) + " differ from the creation flags " + hex(made.flags);
        else if (made.instance_count < info.instance_count)
            why = "instanceCount is above dst's " + std::to_string(made.instance_count);
        else if (made.geometries.size() < info.geometries.size())
            why = "geometryCount is above dst's " + std::to_string(made.geometries.size());
        for (size_t g = 0; why.empty() && g < info.geometries.size(); ++g) {
            const NvGeometry &b = info.geometries[g], &m = made.geometries[g];
            if (b.triangles.vertex_count > m.triangles.vertex_count ||
                b.triangles.index_count > m.triangles.index_count || b.aabbs.count > m.aabbs.count)
                why = "pGeometries[" + std::to_string(g) +
                      "] has more vertices, indices or AABBs than dst was created with";
        }
        if (!why.empty()) {
            c.finding(kVuidNvDstCompatible, "dst " + hex(cmd.dst.handle) + ": the build's " + why);
            ok = false;
        }
    }
    return ok;
}

// An update's src: given, built with ALLOW_UPDATE, not aliasing dst.
bool check_update_source(Context& c) {
    const NvBuildCommand& cmd = c.command;
    bool ok = true;
    if (cmd.update) {
        if (cmd.src.handle == 0) {
            c.finding(kVuidNvUpdateNoSrc, "update is VK_TRUE but src is VK_NULL_HANDLE");
            ok = false;
        } else if (!cmd.src.built ||
                   !(cmd.src.built_flags & VK_BUILD_ACCELERATION_STRUCTURE_ALLOW_UPDATE_BIT_NV)) {
            c.finding(kVuidNvUpdateNotAllowed,
                      "update from src " + hex(cmd.src.handle) +
                          (cmd.src.built ? ", whose last build had no ALLOW_UPDATE flag"
                                         : ", which was never built"));
            ok = false;
        } else if (cmd.src.handle != cmd.dst.handle && cmd.src.bound && cmd.dst.bound &&
                   overlaps(cmd.src.address, cmd.src.size, cmd.dst.address, cmd.dst.size)) {
            c.finding(kVuidNvUpdateAliasing,
                      "src " + hex(cmd.src.handle) + " and dst " + hex(cmd.dst.handle) +
                          " are different objects whose memory overlaps at " +
                          hex(std::max(cmd.src.address, cmd.dst.address)),
                      std::max(cmd.src.address, cmd.dst.address));
        }
    }
    return ok;
}

// Scratch and instance buffer usage and the scratch size; records the scratch access.
void check_scratch(Context& c) {
    const NvBuildCommand& cmd = c.command;
    const NvObjectInfo& info = cmd.info;
    const NvMemoryRequirements need = nv_memory_requirements(info);
    const uint64_t scratch_need = cmd.update ? need.update_scratch : need.build_scratch;
    if (!cmd.scratch_ray_tracing_usage)
        c.finding(kVuidNvScratchUsage,
                  "scratch was created without VK_BUFFER_USAGE_RAY_TRACING_BIT_NV");
    if (cmd.instance_address != 0 && !cmd.instance_buffer_ray_tracing_usage)
        c.finding(kVuidNvInstanceUsage,
                  "instanceData was created without VK_BUFFER_USAGE_RAY_TRACING_BIT_NV");
    if (scratch_need > cmd.scratch_available)
        c.finding(cmd.update ? kVuidNvUpdateScratch : kVuidNvBuildScratch,
                  "scratch holds " + std::to_string(cmd.scratch_available) +
                      " bytes after scratchOffset; the " + (cmd.update ? "update" : "build") +
                      " scratch requirement is " + std::to_string(scratch_need),
                  cmd.scratch_address);
    c.record.scratch_address = cmd.scratch_address;
    c.record.scratch_bytes_used = std::min(scratch_need, cmd.scratch_available);
    c.scratch_used = c.record.scratch_bytes_used;
    c.access(cmd.scratch_address, c.scratch_used, kAccessScratch, true, c.dialect.scratch);
}

// The worst case for these counts must fit before anything is allocated: hostile counts
// end here, not in a huge allocation.
bool check_object_fits(Context& c) {
    const NvBuildCommand& cmd = c.command;
    const NvObjectInfo& info = cmd.info;
    const bool top = info.type == VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_NV;
    bool ok = true;
    uint64_t active_bound = 0;
    for (const NvGeometry& g : info.geometries) active_bound += input_primitives(g);
    if (top) active_bound = info.instance_count;
    const uint64_t bound = nv_memory_requirements(top, info.geometries.size(), active_bound).object;
    if (bound > cmd.dst.size) {
        c.finding(kRuleNvObjectTooLarge,
                  "the engine's object for this build may need " + std::to_string(bound) +
                      " bytes; dst " + hex(cmd.dst.handle) + " has " +
                      std::to_string(cmd.dst.size) + " bytes bound",
                  cmd.dst.address);
        ok = false;
    } else {
        try {
            (void)c.memory.read_bytes(cmd.dst.address, bound, FieldRef{"dst", -1});
        } catch (const MemoryFault& f) {
            c.finding(kRuleNvMemoryFault, "dst " + hex(cmd.dst.handle) + ": " + f.message,
                      cmd.dst.address);
            ok = false;
        }
    }
    return ok;
}

// Command-level rules that need no memory. False when the build cannot run.
bool check_command(Context& c) {
    const NvObjectInfo& info = c.command.info;
    if (info.type != VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_NV &&
        info.type != VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_NV) {
        c.finding("VUID-VkAccelerationStructureInfoNV-type-parameter",
                  "pInfo->type " + std::to_string(uint32_t(info.type)) +
                      " is neither top nor bottom level");
        return false;
    }
    bool ok = check_info_counts(c);
    ok &= check_dst(c);
    ok &= check_update_source(c);
    check_scratch(c);
    if (ok) ok = check_object_fits(c);
    return ok;
}

// An object ready to be written into dst: its size, and the writer of its bytes (built
// objects are written in place, without a staging copy of the whole object).
struct ObjectBytes {
    uint64_t size = 0;
    std::function<void(std::byte*)> write;
};

ObjectBytes bytes_of(std::vector<std::byte> bytes) {
    auto held = std::make_shared<std::vector<std::byte>>(std::move(bytes));
    return ObjectBytes{held->size(),
                       [held](std::byte* out) { std::memcpy(out, held->data(), held->size()); }};
}

// Fills the header's layout fields (header, geometries, records, nodes) and root bounds.
NvObjectHeader lay_out(NvObjectHeader h, size_t geometry_count, uint64_t records_size,
                       std::span<const NvNode> nodes) {
    h.magic = kNvObjectMagic;
    h.format_version = kNvFormatVersion;
    h.geometries_offset = sizeof(NvObjectHeader);
    h.primitives_offset = h.geometries_offset + geometry_count * sizeof(NvGeometryRecord);
    h.nodes_offset = h.primitives_offset + records_size;
    h.object_size = h.nodes_offset + nodes.size_bytes();
    h.geometry_count = uint32_t(geometry_count);
    h.node_count = uint32_t(nodes.size());
    const Box root =
        nodes.empty()
            ? Box::empty()
            : Box{{nodes[0].bounds_min[0], nodes[0].bounds_min[1], nodes[0].bounds_min[2]},
                  {nodes[0].bounds_max[0], nodes[0].bounds_max[1], nodes[0].bounds_max[2]}};
    std::memcpy(h.bounds_min, root.lo, 12);
    std::memcpy(h.bounds_max, root.hi, 12);
    return h;
}

// `write_records(dst)` writes the record bytes in place.
template <class WriteRecords>
void write_object(std::byte* out, const NvObjectHeader& h,
                  std::span<const NvGeometryRecord> geometries, WriteRecords& write_records,
                  std::span<const NvNode> nodes) {
    std::memcpy(out, &h, sizeof h);
    if (!geometries.empty())
        std::memcpy(out + h.geometries_offset, geometries.data(), geometries.size_bytes());
    write_records(out + h.primitives_offset);
    if (!nodes.empty()) std::memcpy(out + h.nodes_offset, nodes.data(), nodes.size_bytes());
}

// The active primitives' records in tree order (`order` indexes the active ones): a gather,
// the records fetched ahead since consecutive leaves' records lie far apart in input order.
// Where every primitive is active the active index is the record index, with no lookup.
template <bool AllActive>
void gather_records(const nv::BottomInput& in, std::span<const uint32_t> order, std::byte* dst) {
    const NvPrimitiveRecord* records = in.primitives.data();
    const uint32_t* source = in.source.data();
    auto record = [&](size_t k) { return records + (AllActive ? order[k] : source[order[k]]); };
    constexpr size_t kAhead = 16;
    const size_t n = order.size();
    for (size_t k = 0; k < n; ++k) {
        if (k + kAhead < n) __builtin_prefetch(record(k + kAhead));
        std::memcpy(dst + k * sizeof(NvPrimitiveRecord), record(k), sizeof(NvPrimitiveRecord));
    }
}

void write_tree_records(const nv::BottomInput& in, std::span<const uint32_t> order,
                        std::byte* dst) {
    if (in.source.size() == in.primitives.size())
        gather_records<true>(in, order, dst);
    else
        gather_records<false>(in, order, dst);
}

// `in` must outlive the returned writer.
ObjectBytes build_bottom(const nv::BottomInput& in, uint32_t flags) {
    // PREFER_FAST_BUILD alone picks the Morton builder; with PREFER_FAST_TRACE (an invalid
    // pair, reported) or neither, the SAH builder.
    const bool fast_build = (flags & VK_BUILD_ACCELERATION_STRUCTURE_PREFER_FAST_BUILD_BIT_NV) &&
                            !(flags & VK_BUILD_ACCELERATION_STRUCTURE_PREFER_FAST_TRACE_BIT_NV);
    nv::Tree tree = fast_build ? nv::build_tree(in.boxes, nv::TreeQuality::kMorton,
                                                nv::TreeLevel::kBottom, &in.centroids)
                               : nv::build_tree(in.boxes, nv::TreeQuality::kSah);
    NvObjectHeader h{};
    h.kind = uint8_t(NvObjectKind::kBottomLevel);
    h.build_flags = flags;
    h.geometry_type = in.aabbs ? VK_GEOMETRY_TYPE_AABBS_NV : VK_GEOMETRY_TYPE_TRIANGLES_NV;
    h.primitive_count = uint32_t(tree.order.size());
    h.input_count = uint32_t(in.primitives.size());
    h = lay_out(h, in.geometries.size(), tree.order.size() * sizeof(NvPrimitiveRecord), tree.nodes);
    auto held = std::make_shared<nv::Tree>(std::move(tree));
    return ObjectBytes{h.object_size, [h, held, &in](std::byte* out) {
                           const nv::Tree& t = *held;
                           auto write_records = [&](std::byte* dst) {
                               write_tree_records(in, t.order, dst);
                           };
                           write_object(out, h, in.geometries, write_records, t.nodes);
                           nv::recycle_tree(std::move(*held));
                       }};
}

std::vector<std::byte> build_top(const nv::TopInput& in, uint32_t flags) {
    std::vector<Box> boxes;
    std::vector<uint32_t> source;
    for (uint32_t i = 0; i < in.instances.size(); ++i) {
        const NvInstanceRecord& r = in.instances[i];
        Box b{{r.world_min[0], r.world_min[1], r.world_min[2]},
              {r.world_max[0], r.world_max[1], r.world_max[2]}};
        if (!r.active || !b.valid()) continue;
        boxes.push_back(b);
        source.push_back(i);
    }
    nv::Tree tree = nv::build_tree(boxes, nv::TreeQuality::kSah, nv::TreeLevel::kTop);
    // Leaves index instance records directly (records stay in input order: gl_InstanceID
    // is the record's index), so the tree's order becomes a permutation in the leaves.
    // Leaves of one instance each keep that simple.
    std::vector<NvNode> nodes;
    nodes.reserve(tree.nodes.size() * 2);
    // Re-expand leaves with several items into chains of single-item leaves.
    std::function<uint32_t(uint32_t)> copy = [&](uint32_t old) -> uint32_t {
        const NvNode n = tree.nodes[old];
        const uint32_t at = uint32_t(nodes.size());
        nodes.push_back(n);
        if (n.count == 0) {
            copy(old + 1);
            const uint32_t right = copy(n.first);
            nodes[at].first = right;
            return at;
        }
        // Leaf of n.count items -> a right-leaning chain of interior nodes over single leaves.
        uint32_t cur = at;
        for (uint32_t k = 0; k < n.count; ++k) {
            const uint32_t item = source[tree.order[n.first + k]];
            const NvInstanceRecord& r = in.instances[item];
            NvNode leaf{};
            std::memcpy(leaf.bounds_min, r.world_min, 12);
            std::memcpy(leaf.bounds_max, r.world_max, 12);
            leaf.first = item;
            leaf.count = 1;
            if (k + 1 == n.count) {
                nodes[cur] = leaf;
                break;
            }
            nodes[cur].count = 0;  // interior: left = leaf (cur + 1), right = the rest
            nodes.push_back(leaf);
            const uint32_t rest = uint32_t(nodes.size());
            nodes.push_back(n);
            nodes[cur].first = rest;
            cur = rest;
        }
        return at;
    };
    if (!tree.nodes.empty()) copy(0);
    nv::recycle_tree(std::move(tree));  // its arrays serve the thread's next bottom level
    nv::refit_tree(std::span(nodes), [&](uint32_t i) {
        const NvInstanceRecord& r = in.instances[i];
        return Box{{r.world_min[0], r.world_min[1], r.world_min[2]},
                   {r.world_max[0], r.world_max[1], r.world_max[2]}};
    });
    NvObjectHeader h{};
    h.kind = uint8_t(NvObjectKind::kTopLevel);
    h.build_flags = flags;
    h.primitive_count = uint32_t(in.instances.size());
    h.input_count = uint32_t(in.instances.size());
    const auto records = std::as_bytes(std::span(in.instances));
    auto write_records = [&](std::byte* dst) {
        if (!records.empty()) std::memcpy(dst, records.data(), records.size());
    };
    h = lay_out(h, 0, records.size(), nodes);
    std::vector<std::byte> out(h.object_size);
    write_object(out.data(), h, {}, write_records, nodes);
    return out;
}

// The src object for an update, checked; nullopt (with a finding) when src holds none.
std::optional<std::vector<std::byte>> read_src(Context& c) {
    const NvObjectBinding& src = c.command.src;
    std::string error;
    try {
        auto head = c.memory.read_bytes(src.address, sizeof(NvObjectHeader),
                                        FieldRef{c.dialect.src.c_str(), -1});
        if (auto h = read_nv_header(head, &error)) {
            auto bytes = c.memory.read_bytes(src.address, h->object_size,
                                             FieldRef{c.dialect.src.c_str(), -1});
            if (open_nv_object(bytes, &error)) {
                c.access(src.address, h->object_size, kAccessObjectRead, false, c.dialect.src);
                return std::vector<std::byte>(bytes.begin(), bytes.end());
            }
        }
    } catch (const MemoryFault& f) {
        error = f.message;
    }
    c.finding(c.dialect.src_not_built,
              "update source " + c.dialect.src + " " + hex(src.handle) + " at " + hex(src.address) +
                  " holds no engine NV object: " + error,
              src.address);
    return std::nullopt;
}

template <class T>
void store(std::vector<std::byte>& bytes, uint64_t offset, const T& value) {
    std::memcpy(bytes.data() + offset, &value, sizeof(T));
}

void set_root_bounds(std::vector<std::byte>& bytes, NvObjectHeader& h,
                     std::span<const NvNode> nodes) {
    Box root = Box::empty();
    if (!nodes.empty())
        root = Box{{nodes[0].bounds_min[0], nodes[0].bounds_min[1], nodes[0].bounds_min[2]},
                   {nodes[0].bounds_max[0], nodes[0].bounds_max[1], nodes[0].bounds_max[2]}};
    std::memcpy(h.bounds_min, root.lo, 12);
    std::memcpy(h.bounds_max, root.hi, 12);
    ++h.update_count;
    store(bytes, 0, h);
    if (!nodes.empty())
        std::memcpy(bytes.data() + h.nodes_offset, nodes.data(), nodes.size_bytes());
}

std::string topology_change(const NvObjectView& src, const nv::BottomInput& in) {
    if (src.header.kind != uint8_t(NvObjectKind::kBottomLevel)) return "src is a top-level object";
    if (src.header.geometry_count != in.geometries.size())
        return "geometryCount " + std::to_string(in.geometries.size()) + " differs from src's " +
               std::to_string(src.header.geometry_count);
    if (!in.geometries.empty() &&
        src.header.geometry_type !=
            uint32_t(in.aabbs ? VK_GEOMETRY_TYPE_AABBS_NV : VK_GEOMETRY_TYPE_TRIANGLES_NV))
        return "geometryType differs from src's";
    for (uint32_t g = 0; g < in.geometries.size(); ++g) {
        const NvGeometryRecord a = src.geometry(g), &b = in.geometries[g];
        const std::string at = "pGeometries[" + std::to_string(g) + "]: ";
        if (a.input_primitives != b.input_primitives)
            return at + std::to_string(b.input_primitives) + " primitives, src has " +
                   std::to_string(a.input_primitives);
        if (a.vertex_format != b.vertex_format) return at + "vertexFormat differs from src's";
        if (a.index_type != b.index_type) return at + "indexType differs from src's";
        if (a.vertex_count != b.vertex_count)
            return at + (in.aabbs ? "stride" : "vertexCount") + std::string(" differs from src's");
        if (a.has_transform != b.has_transform)
            return at + "transformData presence differs from src's";
        if (a.geometry_flags != b.geometry_flags) return at + "flags differ from src's";
    }
    return {};
}

std::optional<std::vector<std::byte>> update_bottom(Context& c, const NvObjectView& src,
                                                    const nv::BottomInput& in) {
    const std::string change = topology_change(src, in);
    if (!change.empty()) {
        c.finding(c.dialect.update_topology,
                  "update: " + change + "; the engine rebuilds dst from scratch",
                  c.command.src.address);
        return std::nullopt;
    }
    std::vector<uint64_t> first(in.geometries.size() + 1, 0);
    for (size_t g = 0; g < in.geometries.size(); ++g)
        first[g + 1] = first[g] + in.geometries[g].input_primitives;
    std::vector<uint8_t> was_active(in.primitives.size(), 0);
    std::vector<std::byte> bytes(src.bytes.begin(), src.bytes.end());
    NvObjectHeader h = src.header;
    std::vector<NvPrimitiveRecord> records(h.primitive_count);
    for (uint32_t k = 0; k < h.primitive_count; ++k) {
        const NvPrimitiveRecord old = src.primitive(k);
        const uint64_t index = first[old.geometry_index] + old.primitive_index;
        if (old.primitive_index >= in.geometries[old.geometry_index].input_primitives)
            return std::nullopt;  // damaged src
        was_active[index] = 1;
        records[k] = in.primitives[index];
        if (!in.active[index])
            c.finding(c.dialect.made_inactive,
                      "update: pGeometries[" + std::to_string(old.geometry_index) + "] primitive " +
                          std::to_string(old.primitive_index) +
                          " was active in src and is inactive now");
    }
    for (size_t i = 0; i < in.primitives.size(); ++i)
        if (in.active[i] && !was_active[i])
            c.finding(
                c.dialect.made_active,
                "update: pGeometries[" + std::to_string(in.primitives[i].geometry_index) +
                    "] primitive " + std::to_string(in.primitives[i].primitive_index) +
                    " was inactive in src and is active now (it stays out of the refit tree)");
    std::memcpy(bytes.data() + h.primitives_offset, records.data(),
                records.size() * sizeof(NvPrimitiveRecord));
    std::vector<NvNode> nodes(h.node_count);
    for (uint32_t i = 0; i < h.node_count; ++i) nodes[i] = src.node(i);
    nv::refit_tree(std::span(nodes), [&](uint32_t i) {
        const NvPrimitiveRecord& p = records[i];
        return in.aabbs ? Box{{p.v[0], p.v[1], p.v[2]}, {p.v[3], p.v[4], p.v[5]}}
                        : nv::triangle_box(p.v);
    });
    set_root_bounds(bytes, h, nodes);
    return bytes;
}

std::optional<std::vector<std::byte>> update_top(Context& c, const NvObjectView& src,
                                                 const nv::TopInput& in) {
    if (src.header.kind != uint8_t(NvObjectKind::kTopLevel) ||
        src.header.primitive_count != in.instances.size()) {
        c.finding(
            c.dialect.update_topology,
            src.header.kind != uint8_t(NvObjectKind::kTopLevel)
                ? std::string(
                      "update: src is a bottom-level object; the engine rebuilds dst from scratch")
                : "update: instanceCount " + std::to_string(in.instances.size()) +
                      " differs from src's " + std::to_string(src.header.primitive_count) +
                      "; the engine rebuilds dst from scratch",
            c.command.src.address);
        return std::nullopt;
    }
    std::vector<uint8_t> in_tree(in.instances.size(), 0);
    std::vector<NvNode> nodes(src.header.node_count);
    for (uint32_t i = 0; i < src.header.node_count; ++i) {
        nodes[i] = src.node(i);
        if (nodes[i].count) in_tree[nodes[i].first] = 1;
    }
    std::vector<NvInstanceRecord> records = in.instances;
    for (uint32_t i = 0; i < records.size(); ++i) {
        const NvInstanceRecord old = src.instance(i);
        if (old.active && !records[i].active)
            c.finding(c.dialect.made_inactive, "update: instance " + std::to_string(i) +
                                                   " was active in src and its reference is 0 now");
        if (!old.active && records[i].active)
            c.finding(
                c.dialect.made_active,
                "update: instance " + std::to_string(i) +
                    " was inactive in src and is active now (it stays out of the refit tree)");
        if (!in_tree[i]) {  // keep the topology: an instance outside the tree stays outside
            Box e = Box::empty();
            std::memcpy(records[i].world_min, e.lo, 12);
            std::memcpy(records[i].world_max, e.hi, 12);
        }
    }
    std::vector<std::byte> bytes(src.bytes.begin(), src.bytes.end());
    NvObjectHeader h = src.header;
    std::memcpy(bytes.data() + h.primitives_offset, records.data(),
                records.size() * sizeof(NvInstanceRecord));
    nv::refit_tree(std::span(nodes), [&](uint32_t i) {
        const NvInstanceRecord& r = records[i];
        return Box{{r.world_min[0], r.world_min[1], r.world_min[2]},
                   {r.world_max[0], r.world_max[1], r.world_max[2]}};
    });
    set_root_bounds(bytes, h, nodes);
    return bytes;
}

// Whole-command overlap rules: scratch against everything else, inputs against dst.
void check_overlaps(Context& c, uint64_t dst_size) {
    const NvBuildCommand& cmd = c.command;
    const std::vector<MemoryAccess> accesses = c.record.accesses;  // findings do not add any
    for (const MemoryAccess& a : accesses) {
        if (a.field == c.dialect.scratch || a.op_index != c.op_index) continue;
        if (overlaps(a.begin, a.end - a.begin, cmd.scratch_address, c.scratch_used))
            c.finding(c.dialect.scratch_overlap,
                      c.dialect.scratch + " [" + hex(cmd.scratch_address) + ", +" +
                          std::to_string(c.scratch_used) + ") overlaps " + a.field + " [" +
                          hex(a.begin) + ", " + hex(a.end) + ")",
                      std::max(a.begin, cmd.scratch_address));
        if (!a.is_write && a.field != c.dialect.src &&
            overlaps(a.begin, a.end - a.begin, cmd.dst.address, dst_size))
            c.finding(c.dialect.input_overlaps_dst,
                      a.field + " [" + hex(a.begin) + ", " + hex(a.end) + ") overlaps " +
                          c.dialect.dst + "'s memory",
                      std::max(a.begin, cmd.dst.address));
    }
    if (overlaps(cmd.dst.address, dst_size, cmd.scratch_address, c.scratch_used))
        c.finding(c.dialect.dst_overlaps_scratch,
                  c.dialect.scratch + " overlaps " + c.dialect.dst + "'s memory",
                  std::max(cmd.dst.address, cmd.scratch_address));
}

}  // namespace

namespace nv {

void run_build(Context& c) {
    const bool top = c.command.info.type == VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_NV;
    std::optional<ObjectBytes> object;
    nv::TopInput top_in;
    nv::BottomInput bottom_in;  // read by object->write
    // Its arrays go back to the thread's kept ones however the build ends.
    struct Recycle {
        nv::BottomInput& in;
        ~Recycle() { nv::recycle_bottom_input(std::move(in)); }
    } recycle{bottom_in};
    try {
        std::optional<std::vector<std::byte>> src;
        if (c.command.update) src = read_src(c);
        std::optional<NvObjectView> src_view;
        if (src) {
            src_view = open_nv_object(*src, nullptr);
            if (!(src_view->header.build_flags &
                  VK_BUILD_ACCELERATION_STRUCTURE_ALLOW_UPDATE_BIT_NV)) {
                c.finding(c.dialect.update_not_allowed,
                          "update from " + c.dialect.src + " " + hex(c.command.src.handle) +
                              ": the build that wrote its bytes had no ALLOW_UPDATE flag");
                src_view.reset();
            }
        }
        if (c.command.update && !src_view) {
            return;  // nothing defined to update from
        }
        if (top) {
            top_in = nv::gather_top(c);
            if (src_view)
                if (auto updated = update_top(c, *src_view, top_in))
                    object = bytes_of(std::move(*updated));
            if (!object) object = bytes_of(build_top(top_in, c.command.info.flags));
        } else {
            bottom_in = nv::gather_bottom(c);
            if (src_view)
                if (auto updated = update_bottom(c, *src_view, bottom_in))
                    object = bytes_of(std::move(*updated));
            if (!object) object = build_bottom(bottom_in, c.command.info.flags);
        }
    } catch (const MemoryFault& f) {
        c.finding(c.dialect.memory_fault, f.message, f.address);
        return;
    }
    if (object->size > c.command.dst.size) {
        c.finding(c.dialect.object_too_large,
                  "the engine's object needs " + std::to_string(object->size) + " bytes; " +
                      c.dialect.dst + " " + hex(c.command.dst.handle) + " has " +
                      std::to_string(c.command.dst.size) + " bytes bound",
                  c.command.dst.address);
        return;
    }
    check_overlaps(c, object->size);
    try {
        auto out = c.memory.write_bytes(c.command.dst.address, object->size,
                                        FieldRef{c.dialect.dst.c_str(), -1});
        object->write(out.data());
    } catch (const MemoryFault& f) {
        c.finding(c.dialect.memory_fault, f.message, f.address);
        return;
    }
    c.access(c.command.dst.address, object->size, kAccessObjectWrite, true, c.dialect.dst);
    OpResult& op = c.record.ops[c.op_index < 0 ? 0 : size_t(c.op_index)];
    op.executed = true;
    op.dst_address = c.command.dst.address;
    op.dst_size = object->size;
}

}  // namespace nv

NvMemoryRequirements nv_memory_requirements(const NvObjectInfo& info) {
    const bool top = info.type == VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_NV;
    uint64_t count = top ? info.instance_count : 0;
    if (!top)
        for (const NvGeometry& g : info.geometries) count += input_primitives(g);
    return nv_memory_requirements(top, top ? 0 : info.geometries.size(), count);
}

ExecutionRecord execute_nv_build(const NvBuildCommand& command, MemoryImage& memory,
                                 const NvBuildOptions& options) {
    ExecutionRecord record;
    record.op_count = 1;
    record.ops.resize(1);
    Context c{command, memory, options, record, {}};
    if (!check_command(c)) {
        c.close();
        return record;
    }
    nv::run_build(c);
    c.close();
    return record;
}

}  // namespace clastrace::engine
