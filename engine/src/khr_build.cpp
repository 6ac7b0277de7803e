// SPDX-License-Identifier: Apache-2.0
// vkCmdBuildAccelerationStructuresKHR: each element of pInfos becomes the NV form of the
// same build (the geometry's addresses with the range's offsets applied), is checked with
// the KHR rules (khr_checks.cpp) and run by the NV machinery under the KHR names.
#include "clastrace/engine/khr_build.h"

#include "clastrace/engine/vertex_format.h"
#include "khr_internal.h"

#include <algorithm>

namespace clastrace::engine {
namespace khr {

std::string info_prefix(size_t info) { return "pInfos[" + std::to_string(info) + "]."; }

std::vector<uint32_t> primitive_counts(const KhrBuildInfo& info) {
    std::vector<uint32_t> counts;
    for (const KhrBuildRange& r : info.ranges) counts.push_back(r.primitive_count);
    return counts;
}

bool ranges_overlap(uint64_t a, uint64_t an, uint64_t b, uint64_t bn) {
    if (an == 0 || bn == 0) return false;
    const uint64_t ae = a + an < a ? ~0ull : a + an, be = b + bn < b ? ~0ull : b + bn;
    return a < be && b < ae;
}

}  // namespace khr

namespace {

uint32_t khr_vertex_size(VkFormat format) { return vertex_format_info(format).size; }
uint32_t khr_component_size(VkFormat format) { return vertex_format_info(format).component_size; }
bool khr_decode_vertex(VkFormat format, const std::byte* src, float xyz[3]) {
    if (!vertex_format_info(format).supported) return false;
    decode_vertex(format, src, xyz);
    return true;
}

nv::Dialect khr_dialect(size_t index, const KhrBuildInfo& info) {
    const std::string p = khr::info_prefix(index);
    nv::Dialect d;
    d.geometries = p + "pGeometries";
    d.instances = p + "pGeometries[0].geometry.instances.data";
    d.src = p + "srcAccelerationStructure";
    d.dst = p + "dstAccelerationStructure";
    d.scratch = p + "scratchData";
    d.vertex_count = "maxVertex + 1 - firstVertex";
    d.formats_by = "the engine (VK_FORMAT_FEATURE_ACCELERATION_STRUCTURE_VERTEX_BUFFER_BIT_KHR)";
    d.reference_source = "address vkGetAccelerationStructureDeviceAddressKHR gave";
    d.vertex_size = khr_vertex_size;
    d.component_size = khr_component_size;
    d.decode_vertex = khr_decode_vertex;
    d.vertex_format = kRuleUnsupportedFormat;
    d.reference = kVuidKhrReference;
    d.reference_alignment = kVuidKhrPointerAlignment;
    d.blas_not_built = kRuleKhrBlasNotBuilt;
    d.nan_component = kRuleKhrNanComponent;
    d.index_out_of_range = kRuleKhrIndexAboveMaxVertex;
    d.update_not_allowed = kVuidKhrUpdateNotAllowed;
    d.made_inactive = kVuidKhrMadeInactive;
    d.made_active = kVuidKhrMadeActive;
    d.update_topology = kRuleKhrUpdateTopology;
    d.src_not_built = kRuleKhrSrcNotBuilt;
    d.memory_fault = kRuleKhrMemoryFault;
    d.object_too_large = kRuleKhrObjectTooLarge;
    d.scratch_overlap = kRuleKhrScratchOverlap;
    d.dst_overlaps_scratch = kVuidKhrDstOverlapsScratch;
    d.input_overlaps_dst = kRuleKhrInputOverlapsDst;
    d.instance_pointers = info.type == VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_KHR &&
                          !info.geometries.empty() &&
                          info.geometries[0].instances.array_of_pointers;
    return d;
}

NvObjectBinding nv_binding(const KhrObject& o) {
    NvObjectBinding b;
    b.handle = o.handle;
    b.bound = o.bound;
    b.address = o.address;
    b.size = o.size;
    return b;
}

// Triangles with the range applied: NV's vertex_address is the first vertex an index
// counts from, its vertex_count the vertices an index may reach.
NvTriangles nv_triangles(const KhrTriangles& t, const KhrBuildRange& r) {
    NvTriangles n;
    n.vertex_format = t.vertex_format;
    n.vertex_stride = t.vertex_stride;
    n.index_type = t.index_type;
    const uint64_t first = uint64_t(r.first_vertex) * t.vertex_stride;
    if (t.index_type == VK_INDEX_TYPE_NONE_KHR) {
        n.vertex_address = t.vertex_data + r.primitive_offset + first;
        n.vertex_count = r.primitive_count * 3;  // primitive_count is bounded by the limits
    } else {
        n.index_address = t.index_data + r.primitive_offset;
        n.index_count = r.primitive_count * 3;
        n.vertex_address = t.vertex_data + first;
        const uint64_t reach = uint64_t(t.max_vertex) + 1;
        n.vertex_count = uint32_t(
            std::min<uint64_t>(reach > r.first_vertex ? reach - r.first_vertex : 0, 0xFFFFFFFFull));
    }
    if (t.transform_data != 0) n.transform_address = t.transform_data + r.transform_offset;
    return n;
}

// The NV form of one info; its ranges are already known to match its geometries.
NvBuildCommand nv_command(const KhrBuildInfo& info) {
    NvBuildCommand cmd;
    const bool top = info.type == VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_KHR;
    cmd.info.type = top ? VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_NV
                        : VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_NV;
    cmd.info.flags = info.flags;
    if (top) {
        cmd.info.instance_count = info.ranges[0].primitive_count;
        cmd.instance_address = info.geometries[0].instances.data + info.ranges[0].primitive_offset;
    } else {
        for (size_t g = 0; g < info.geometries.size(); ++g) {
            const KhrGeometry& k = info.geometries[g];
            const KhrBuildRange& r = info.ranges[g];
            NvGeometry n;
            n.flags = k.flags;
            if (k.type == VK_GEOMETRY_TYPE_AABBS_KHR) {
                n.type = VK_GEOMETRY_TYPE_AABBS_NV;
                n.aabbs.address = k.aabbs.data + r.primitive_offset;
                n.aabbs.count = r.primitive_count;
                n.aabbs.stride = uint32_t(k.aabbs.stride);  // checked below 2^32
            } else {
                n.triangles = nv_triangles(k.triangles, r);
            }
            cmd.info.geometries.push_back(n);
        }
    }
    cmd.update = info.mode == VK_BUILD_ACCELERATION_STRUCTURE_MODE_UPDATE_KHR;
    cmd.dst = nv_binding(info.dst);
    cmd.src = nv_binding(info.src);
    cmd.scratch_address = info.scratch_address;
    cmd.scratch_available = info.scratch_available;
    return cmd;
}

// The parts of an info its NV form needs to exist at all (counts that match).
bool translatable(const KhrBuildInfo& info) {
    if (info.ranges.size() != info.geometries.size()) return false;
    if (info.type == VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_KHR)
        return info.geometries.size() == 1 &&
               info.geometries[0].type == VK_GEOMETRY_TYPE_INSTANCES_KHR;
    return info.type == VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR;
}

}  // namespace

KhrBuildSizes khr_build_sizes(VkAccelerationStructureTypeKHR type,
                              std::span<const KhrGeometry> geometries,
                              std::span<const uint32_t> max_primitive_counts) {
    const bool top = type == VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_KHR;
    uint64_t count = 0;
    for (uint32_t n : max_primitive_counts) count += n;
    const NvMemoryRequirements r = nv_memory_requirements(top, top ? 0 : geometries.size(), count);
    return KhrBuildSizes{r.object, r.update_scratch, r.build_scratch};
}

ExecutionRecord execute_khr_build(const KhrBuildCommand& command, MemoryImage& memory,
                                  const KhrBuildOptions& options) {
    ExecutionRecord record;
    record.op_count = uint32_t(command.infos.size());
    record.ops.resize(command.infos.size());
    khr::check_between_infos(command, record);
    NvBuildOptions nv_options;
    nv_options.resolve_reference = options.resolve_reference;
    nv_options.max_findings_per_rule = options.max_findings_per_rule;
    for (size_t i = 0; i < command.infos.size(); ++i) {
        const KhrBuildInfo& info = command.infos[i];
        const NvBuildCommand cmd = translatable(info) ? nv_command(info) : NvBuildCommand{};
        nv::Context c{cmd, memory, nv_options, record, {}};
        c.dialect = khr_dialect(i, info);
        c.op_index = int64_t(i);
        if (khr::check_info(c, info, options.limits)) {
            if (i == 0) record.scratch_address = info.scratch_address;
            if (i == 0) record.scratch_bytes_used = c.scratch_used;
            nv::run_build(c);
        }
        c.close();
    }
    khr::check_instances_against_dsts(command, record);
    return record;
}

}  // namespace clastrace::engine
