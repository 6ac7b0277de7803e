// SPDX-License-Identifier: Apache-2.0
// The vkCmdBuildAccelerationStructuresKHR rules that the command's parameters and memory
// decide: per info (modes, types, counts, alignments, sizes, the update's source) and
// between the infos of one command (aliasing of dst, src and scratch).
#include "clastrace/common/hex.h"
#include "clastrace/engine/vertex_format.h"
#include "khr_internal.h"

#include <algorithm>

namespace clastrace::engine::khr {
namespace {

using common::hex;

const char* geometry_type_name(VkGeometryTypeKHR type) {
    switch (type) {
    case VK_GEOMETRY_TYPE_TRIANGLES_KHR: return "TRIANGLES";
    case VK_GEOMETRY_TYPE_AABBS_KHR: return "AABBS";
    case VK_GEOMETRY_TYPE_INSTANCES_KHR: return "INSTANCES";
    default: return "unknown";
    }
}

// Mode, type and geometry shapes: what the NV form needs. False when the info cannot run.
bool check_shape(nv::Context& c, const KhrBuildInfo& info, const KhrLimits& limits) {
    const std::string at = c.dialect.geometries;
    if (info.mode != VK_BUILD_ACCELERATION_STRUCTURE_MODE_BUILD_KHR &&
        info.mode != VK_BUILD_ACCELERATION_STRUCTURE_MODE_UPDATE_KHR) {
        c.finding(kVuidKhrMode,
                  "mode " + std::to_string(uint32_t(info.mode)) + " is neither BUILD nor UPDATE");
        return false;
    }
    auto bad = [&](const std::string& why) {
        c.finding(kRuleKhrBadInfo, why + " (the engine does not run this info)");
        return false;
    };
    if (info.ranges.size() != info.geometries.size())
        return bad("ppBuildRangeInfos row has " + std::to_string(info.ranges.size()) +
                   " ranges for geometryCount " + std::to_string(info.geometries.size()));
    if (info.geometries.size() > limits.max_geometry_count)
        return bad("geometryCount " + std::to_string(info.geometries.size()) +
                   " exceeds maxGeometryCount");
    if (info.type == VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_KHR) {
        if (info.geometries.size() != 1 ||
            info.geometries[0].type != VK_GEOMETRY_TYPE_INSTANCES_KHR)
            return bad("a top-level build needs exactly one INSTANCES geometry");
        if (info.ranges[0].primitive_count > limits.max_instance_count) {
            c.finding(kVuidKhrInstanceCount, "ppBuildRangeInfos primitiveCount " +
                                                 std::to_string(info.ranges[0].primitive_count) +
                                                 " instances exceeds maxInstanceCount " +
                                                 std::to_string(limits.max_instance_count));
            return false;
        }
        return true;
    }
    if (info.type != VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR)
        return bad("type " + std::to_string(uint32_t(info.type)) + " is neither TOP nor BOTTOM");
    uint64_t primitives = 0;
    for (size_t g = 0; g < info.geometries.size(); ++g) {
        const KhrGeometry& geo = info.geometries[g];
        const std::string here = at + "[" + std::to_string(g) + "]";
        if (geo.type != info.geometries[0].type || geo.type == VK_GEOMETRY_TYPE_INSTANCES_KHR)
            return bad(here + ".geometryType " + geometry_type_name(geo.type) +
                       ": a bottom level holds triangles or AABBs, one type for all geometries");
        primitives += info.ranges[g].primitive_count;
        if (geo.type == VK_GEOMETRY_TYPE_AABBS_KHR &&
            (geo.aabbs.stride % 8 || geo.aabbs.stride > 0xFFFFFFF8ull))
            return bad(here + ".geometry.aabbs.stride " + std::to_string(geo.aabbs.stride) +
                       " is not a multiple of 8 below 2^32");
        if (geo.type != VK_GEOMETRY_TYPE_TRIANGLES_KHR) continue;
        const VkIndexType it = geo.triangles.index_type;
        if (it != VK_INDEX_TYPE_NONE_KHR && it != VK_INDEX_TYPE_UINT16 &&
            it != VK_INDEX_TYPE_UINT32)
            return bad(here + ".geometry.triangles.indexType " + std::to_string(uint32_t(it)) +
                       " is not UINT16, UINT32 or NONE_KHR");
    }
    if (primitives > limits.max_primitive_count)
        return bad("the geometries hold " + std::to_string(primitives) +
                   " primitives, above maxPrimitiveCount " +
                   std::to_string(limits.max_primitive_count));
    return true;
}

// dst bound and of a matching type; an update's src given, bound and not aliasing dst.
bool check_objects(nv::Context& c, const KhrBuildInfo& info) {
    bool ok = true;
    if (info.dst.handle == 0 || !info.dst.bound) {
        c.finding(kVuidKhrDstBound, c.dialect.dst + " " + hex(info.dst.handle) +
                                        ": the buffer it was created on is not bound to memory");
        ok = false;
    }
    const bool top = info.type == VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_KHR;
    if (info.dst.type != info.type && info.dst.type != VK_ACCELERATION_STRUCTURE_TYPE_GENERIC_KHR) {
        c.finding(top ? kVuidKhrTopDstType : kVuidKhrBottomDstType,
                  c.dialect.dst + " " + hex(info.dst.handle) + " was created with type " +
                      std::to_string(uint32_t(info.dst.type)) + " for a " +
                      (top ? "top" : "bottom") + "-level build");
        ok = false;
    }
    if (info.mode != VK_BUILD_ACCELERATION_STRUCTURE_MODE_UPDATE_KHR) return ok;
    if (info.src.handle == 0) {
        c.finding(kVuidKhrUpdateNoSrc,
                  "mode is UPDATE but srcAccelerationStructure is "
                  "VK_NULL_HANDLE");
        return false;
    }
    if (!info.src.bound) {
        c.finding(kVuidKhrSrcBound, c.dialect.src + " " + hex(info.src.handle) +
                                        ": the buffer it was created on is not bound to memory");
        return false;
    }
    if (info.src.handle != info.dst.handle &&
        ranges_overlap(info.src.address, info.src.size, info.dst.address, info.dst.size))
        c.finding(kVuidKhrUpdateAliasing,
                  c.dialect.src + " " + hex(info.src.handle) + " and " + c.dialect.dst + " " +
                      hex(info.dst.handle) + " are different objects whose memory overlaps",
                  std::max(info.src.address, info.dst.address));
    return ok;
}

// An update's type, flags and geometry count against what src was last built with (its
// header; the rest of the topology is compared when the update runs).
void check_update_header(nv::Context& c, const KhrBuildInfo& info) {
    if (info.mode != VK_BUILD_ACCELERATION_STRUCTURE_MODE_UPDATE_KHR) return;
    std::optional<NvObjectHeader> h;
    try {
        h = read_nv_header(c.memory.read_bytes(info.src.address, sizeof(NvObjectHeader),
                                               FieldRef{c.dialect.src.c_str(), c.op_index}),
                           nullptr);
    } catch (const MemoryFault&) {}
    if (!h) return;  // run_build reports a src that holds no object
    const bool top = info.type == VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_KHR;
    if (h->kind != uint8_t(top ? NvObjectKind::kTopLevel : NvObjectKind::kBottomLevel))
        c.finding(kVuidKhrUpdateType,
                  "update: type differs from the one " + c.dialect.src + " was last built with");
    if (h->build_flags != info.flags)
        c.finding(kVuidKhrUpdateFlags, "update: flags " + hex(info.flags) + " differ from " +
                                           hex(h->build_flags) + ", which " + c.dialect.src +
                                           " was last built with");
    if (!top && h->geometry_count != info.geometries.size())
        c.finding(kVuidKhrUpdateGeometryCount,
                  "update: geometryCount " + std::to_string(info.geometries.size()) +
                      " differs from " + std::to_string(h->geometry_count) + ", which " +
                      c.dialect.src + " was last built with");
}

void check_alignment(nv::Context& c, uint64_t address, uint64_t alignment, const char* rule,
                     const std::string& field) {
    if (address % alignment == 0) return;
    c.finding(rule,
              field + " " + hex(address) + " is not aligned to " + std::to_string(alignment) +
                  " bytes",
              address);
}

// The geometry addresses' alignments and the vertex format.
bool check_geometry_data(nv::Context& c, const KhrBuildInfo& info) {
    bool ok = true;
    for (size_t g = 0; g < info.geometries.size(); ++g) {
        const KhrGeometry& geo = info.geometries[g];
        const std::string at = c.dialect.geometries + "[" + std::to_string(g) + "].geometry.";
        if (geo.type == VK_GEOMETRY_TYPE_AABBS_KHR) {
            check_alignment(c, geo.aabbs.data, 8, kVuidKhrAabbAlignment, at + "aabbs.data");
        } else if (geo.type == VK_GEOMETRY_TYPE_INSTANCES_KHR) {
            if (geo.instances.array_of_pointers)
                check_alignment(c, geo.instances.data, 8, kVuidKhrPointersAlignment,
                                at + "instances.data");
            else
                check_alignment(c, geo.instances.data, 16, kVuidKhrInstancesAlignment,
                                at + "instances.data");
        } else {
            const KhrTriangles& t = geo.triangles;
            const VertexFormatInfo format = vertex_format_info(t.vertex_format);
            if (!format.supported) {
                c.finding(kRuleUnsupportedFormat, at + "triangles.vertexFormat " +
                                                      std::to_string(uint32_t(t.vertex_format)) +
                                                      " is no vertex format the engine decodes");
                ok = false;
                continue;
            }
            check_alignment(c, t.vertex_data, format.component_size, kVuidKhrVertexAlignment,
                            at + "triangles.vertexData");
            if (t.index_type != VK_INDEX_TYPE_NONE_KHR)
                check_alignment(c, t.index_data, t.index_type == VK_INDEX_TYPE_UINT16 ? 2 : 4,
                                kVuidKhrIndexAlignment, at + "triangles.indexData");
            if (t.transform_data != 0)
                check_alignment(c, t.transform_data, 16, kVuidKhrTransformAlignment,
                                at + "triangles.transformData");
        }
    }
    return ok;
}

// Scratch alignment and size (claimed for the hazard checker), dst's size against the
// engine's build sizes for these counts. False when dst cannot hold the object.
bool check_sizes(nv::Context& c, const KhrBuildInfo& info, const KhrLimits& limits) {
    const std::vector<uint32_t> counts = primitive_counts(info);
    const KhrBuildSizes need = khr_build_sizes(info.type, info.geometries, counts);
    const bool update = info.mode == VK_BUILD_ACCELERATION_STRUCTURE_MODE_UPDATE_KHR;
    const uint64_t scratch_need = update ? need.update_scratch_size : need.build_scratch_size;
    if (limits.min_scratch_offset_alignment)
        check_alignment(c, info.scratch_address, limits.min_scratch_offset_alignment,
                        kVuidKhrScratchAlignment, c.dialect.scratch + ".deviceAddress");
    if (scratch_need > info.scratch_available)
        c.finding(update ? kVuidKhrUpdateScratch : kVuidKhrBuildScratch,
                  c.dialect.scratch + " holds " + std::to_string(info.scratch_available) +
                      " bytes; the " + (update ? "updateScratchSize" : "buildScratchSize") +
                      " for these primitive counts is " + std::to_string(scratch_need),
                  info.scratch_address);
    c.scratch_used = std::min(scratch_need, info.scratch_available);
    c.access(info.scratch_address, c.scratch_used, kAccessScratch, true, c.dialect.scratch);
    if (need.acceleration_structure_size > info.dst.size) {
        c.finding(kVuidKhrDstSize,
                  c.dialect.dst + " " + hex(info.dst.handle) + " was created with size " +
                      std::to_string(info.dst.size) + "; accelerationStructureSize for these " +
                      "primitive counts is " + std::to_string(need.acceleration_structure_size),
                  info.dst.address);
        return false;
    }
    try {
        (void)c.memory.read_bytes(info.dst.address, need.acceleration_structure_size,
                                  FieldRef{c.dialect.dst.c_str(), c.op_index});
    } catch (const MemoryFault& f) {
        c.finding(kRuleKhrMemoryFault, c.dialect.dst + ": " + f.message, info.dst.address);
        return false;
    }
    return true;
}

}  // namespace

bool check_info(nv::Context& c, const KhrBuildInfo& info, const KhrLimits& limits) {
    if (!check_shape(c, info, limits)) return false;
    bool ok = check_objects(c, info);
    ok &= check_geometry_data(c, info);
    if (!ok) return false;
    check_update_header(c, info);
    return check_sizes(c, info, limits);
}

namespace {

void between(ExecutionRecord& record, const char* rule, size_t i, std::string message,
             uint64_t address) {
    record.findings.push_back(Finding{rule, std::move(message), int64_t(i), address});
}

}  // namespace

void check_between_infos(const KhrBuildCommand& command, ExecutionRecord& record) {
    const auto& infos = command.infos;
    auto update = [](const KhrBuildInfo& b) {
        return b.mode == VK_BUILD_ACCELERATION_STRUCTURE_MODE_UPDATE_KHR && b.src.handle != 0;
    };
    auto scratch_size = [](const KhrBuildInfo& b) {
        const KhrBuildSizes s = khr_build_sizes(b.type, b.geometries, primitive_counts(b));
        return std::min({b.scratch_available, b.scratch_claim,
                         b.mode == VK_BUILD_ACCELERATION_STRUCTURE_MODE_UPDATE_KHR
                             ? s.update_scratch_size
                             : s.build_scratch_size});
    };
    for (size_t i = 0; i < infos.size(); ++i) {
        const KhrBuildInfo& a = infos[i];
        const std::string pa = info_prefix(i);
        for (size_t j = 0; j < infos.size(); ++j) {
            if (i == j) continue;
            const KhrBuildInfo& b = infos[j];
            const std::string pb = info_prefix(j);
            if (j > i && a.dst.handle != 0 && a.dst.handle == b.dst.handle)
                between(record, kVuidKhrSameDst, i,
                        pa + "dstAccelerationStructure and " + pb +
                            "dstAccelerationStructure are the same object " + hex(a.dst.handle),
                        a.dst.address);
            else if (j > i && ranges_overlap(a.dst.address, a.dst.size, b.dst.address, b.dst.size))
                between(record, kVuidKhrDstOverlapsDst, i,
                        pa + "dstAccelerationStructure and " + pb +
                            "dstAccelerationStructure overlap in memory",
                        std::max(a.dst.address, b.dst.address));
            if (update(a) && a.src.handle == b.dst.handle)
                between(record, kVuidKhrSrcIsOtherDst, i,
                        pa + "srcAccelerationStructure is " + pb + "dstAccelerationStructure " +
                            hex(a.src.handle),
                        a.src.address);
            else if (update(b) &&
                     ranges_overlap(a.dst.address, a.dst.size, b.src.address, b.src.size))
                between(record, kVuidKhrDstOverlapsOtherSrc, i,
                        pa + "dstAccelerationStructure overlaps " + pb +
                            "srcAccelerationStructure, which that update reads",
                        std::max(a.dst.address, b.src.address));
            if (ranges_overlap(a.dst.address, a.dst.size, b.scratch_address, scratch_size(b)))
                between(record, kVuidKhrDstOverlapsScratch, i,
                        pa + "dstAccelerationStructure overlaps " + pb + "scratchData",
                        std::max(a.dst.address, b.scratch_address));
            if (j > i && ranges_overlap(a.scratch_address, scratch_size(a), b.scratch_address,
                                        scratch_size(b)))
                between(record, kVuidKhrScratchOverlapsScratch, i,
                        pa + "scratchData and " + pb + "scratchData overlap",
                        std::max(a.scratch_address, b.scratch_address));
            if (update(b) &&
                ranges_overlap(a.scratch_address, scratch_size(a), b.src.address, b.src.size))
                between(record, kVuidKhrScratchOverlapsSrc, i,
                        pa + "scratchData overlaps " + pb + "srcAccelerationStructure",
                        std::max(a.scratch_address, b.src.address));
        }
    }
}

void check_instances_against_dsts(const KhrBuildCommand& command, ExecutionRecord& record) {
    const std::string reference = "].accelerationStructureReference";
    const std::vector<MemoryAccess> accesses = record.accesses;
    for (const MemoryAccess& a : accesses) {
        if (!a.field.ends_with(reference)) continue;
        for (size_t i = 0; i < command.infos.size(); ++i) {
            const KhrObject& dst = command.infos[i].dst;
            if (int64_t(i) == a.op_index) continue;
            if (a.begin == dst.address)
                between(record, kVuidKhrDstInOtherInstances, i,
                        info_prefix(i) + "dstAccelerationStructure is the bottom level " + a.field +
                            " names",
                        dst.address);
            else if (ranges_overlap(a.begin, a.end - a.begin, dst.address, dst.size))
                between(record, kVuidKhrDstOverlapsOtherBlas, i,
                        info_prefix(i) + "dstAccelerationStructure overlaps the bottom level " +
                            a.field + " names",
                        std::max(a.begin, dst.address));
        }
    }
}

}  // namespace clastrace::engine::khr
