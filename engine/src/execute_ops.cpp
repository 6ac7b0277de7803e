// SPDX-License-Identifier: Apache-2.0
// The read phase of one op: decode its src info, check what it references, build the
// object into memory of its own. Writes nothing to the MemoryImage.
#include "clastrace/engine/blas.h"
#include "clastrace/engine/vertex_format.h"
#include "execute_internal.h"

#include "clastrace/common/enum_bits.h"

#include <algorithm>
#include <charconv>
#include <cstring>
#include <optional>
#include <sstream>
#include <string_view>

namespace clastrace::engine::detail {

void Recorder::access(uint64_t begin, uint64_t size, VkAccessFlags2 access, bool is_write,
                      FieldName field) {
    if (size == 0) return;
    uint64_t end = begin + size;
    if (end < begin) end = UINT64_MAX;
    accesses.push_back({begin, end, kStageBuild, access, is_write, std::move(field), op_index});
}

void Recorder::finding(const char* rule, std::string message, uint64_t address) {
    findings.push_back({rule, std::move(message), op_index, address});
}

void Recorder::fault(const MemoryFault& f) { finding(kRuleMemoryFault, f.message, f.address); }

namespace {

constexpr size_t kAccessesPerOp = 8;

// Bytes spanned by `count` elements of `element` bytes at `stride` (0: packed).
std::optional<uint64_t> strided_span(uint64_t count, uint64_t stride, uint64_t element) {
    if (count == 0) return 0;
    if (stride == 0) stride = element;
    uint64_t r;
    if (__builtin_mul_overflow(count - 1, stride, &r) || __builtin_add_overflow(r, element, &r))
        return std::nullopt;
    return r;
}

uint64_t index_size(uint32_t index_type) {
    switch (index_type) {
    case VK_CLUSTER_ACCELERATION_STRUCTURE_INDEX_FORMAT_8BIT_NV: return 1;
    case VK_CLUSTER_ACCELERATION_STRUCTURE_INDEX_FORMAT_16BIT_NV: return 2;
    case VK_CLUSTER_ACCELERATION_STRUCTURE_INDEX_FORMAT_32BIT_NV: return 4;
    default: return 0;
    }
}

// "srcInfosArray[i]" or "srcInfosArray[i].member", kept inline: every op names several.
FieldName field(uint32_t i, const char* member = nullptr) {
    FieldName name("srcInfosArray[");
    name.append_number(i).append("]");
    if (member) name.append(".").append(member);
    return name;
}

// Names the field only when it records it: most ops leave the optional buffers 0.
void record_buffer(Recorder& rec, uint64_t address, uint64_t count, uint64_t stride,
                   uint64_t element, uint32_t i, const char* member) {
    if (address == 0 || count == 0 || element == 0) return;
    if (auto n = strided_span(count, stride, element))
        rec.access(address, *n, kAccessPointedInput, false, field(i, member));
}

// Bytes of one vertex of the input's format, 0 for one no build decodes; by the field's bits,
// which the op has not checked yet (common/enum_bits.h).
uint32_t vertex_bytes(const VkClusterAccelerationStructureTriangleClusterInputNV& in) {
    return vertex_format_info(common::enum_bits(in.vertexFormat)).size;
}

// The inputs a triangle cluster or template build reads, as the spec lays them out.
template <class Info>
void record_triangle_inputs(Recorder& rec, const Info& info,
                            const VkClusterAccelerationStructureTriangleClusterInputNV& in,
                            uint32_t i) {
    record_buffer(rec, info.indexBuffer, uint64_t(info.triangleCount) * 3, info.indexBufferStride,
                  index_size(info.indexType), i, "indexBuffer");
    record_buffer(rec, info.vertexBuffer, info.vertexCount, info.vertexBufferStride,
                  vertex_bytes(in), i, "vertexBuffer");
    record_buffer(rec, info.geometryIndexAndFlagsBuffer, info.triangleCount,
                  info.geometryIndexAndFlagsBufferStride, 4, i, "geometryIndexAndFlagsBuffer");
    if (info.opacityMicromapArray != 0)
        record_buffer(rec, info.opacityMicromapIndexBuffer, info.triangleCount,
                      info.opacityMicromapIndexBufferStride,
                      index_size(info.opacityMicromapIndexType), i, "opacityMicromapIndexBuffer");
}

// `t` is the move input's type by its bits: nothing checks it (common/enum_bits.h).
ObjectType object_type_of(uint32_t t) {
    switch (t) {
    case VK_CLUSTER_ACCELERATION_STRUCTURE_TYPE_CLUSTERS_BOTTOM_LEVEL_NV:
        return ObjectType::kClustersBottomLevel;
    case VK_CLUSTER_ACCELERATION_STRUCTURE_TYPE_TRIANGLE_CLUSTER_TEMPLATE_NV:
        return ObjectType::kTriangleClusterTemplate;
    default: return ObjectType::kTriangleCluster;
    }
}

// Merges the CLAS ranges a BLAS reads into runs (implicitly built CLAS sit back to back),
// so a million references do not become a million records.
void record_cluster_reads(Recorder& rec, uint32_t i,
                          std::vector<std::pair<uint64_t, uint64_t>>& ranges) {
    std::sort(ranges.begin(), ranges.end());
    size_t k = 0;
    while (k < ranges.size()) {
        uint64_t begin = ranges[k].first, end = ranges[k].second;
        size_t first = k;
        while (++k < ranges.size() && ranges[k].first <= end) end = std::max(end, ranges[k].second);
        FieldName name = field(i, "clusterReferences[*]");
        name.append(" (").append_number(k - first).append(" CLAS)");
        rec.access(begin, end - begin, kAccessObjectRead, false, std::move(name));
    }
}

void run_bottom_level(const ResolvedCommand& cmd, const MemoryImage& memory, uint32_t i,
                      uint64_t info_address, OpOutput& out) {
    Recorder& rec = out.rec;
    FieldName f = field(i);
    auto info =
        memory.read<VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV>(info_address,
                                                                                  {f.c_str(), i});
    const auto& in = *cmd.input->opInput.pClustersBottomLevel;
    out.type = ObjectType::kClustersBottomLevel;
    out.clusters = info.clusterReferencesCount;
    if (info.clusterReferencesCount > in.maxClusterCountPerAccelerationStructure)
        rec.finding(kRuleClusterCountAboveInput,
                    field(i, "clusterReferencesCount") + " = " +
                        std::to_string(info.clusterReferencesCount) +
                        " exceeds maxClusterCountPerAccelerationStructure = " +
                        std::to_string(in.maxClusterCountPerAccelerationStructure) + " (op " +
                        std::to_string(i) + ")");
    if (info.clusterReferencesCount > 0 && info.clusterReferencesStride < 8) {
        rec.finding(
            "VUID-VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV-"
            "clusterReferencesStride-10486",
            field(i, "clusterReferencesStride") + " = " +
                std::to_string(info.clusterReferencesStride) + " is less than 8 (op " +
                std::to_string(i) + ")");
        return;
    }
    FieldName refs_field = field(i, "clusterReferences");
    std::span<const std::byte> refs;
    try {
        refs = memory.read_array(info.clusterReferences, info.clusterReferencesCount,
                                 info.clusterReferencesStride, 8, {refs_field.c_str(), i});
    } catch (const MemoryFault& fault) {
        rec.finding(
            "VUID-VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV-clusterReferences-"
            "10485",
            refs_field + " at " + hex(info.clusterReferences) +
                " does not hold clusterReferencesCount = " +
                std::to_string(info.clusterReferencesCount) + " values: " + fault.message,
            info.clusterReferences);
        return;
    }
    rec.access(info.clusterReferences, refs.size(), kAccessPointedInput, false, refs_field);
    std::vector<ClusterBox> boxes;
    boxes.reserve(info.clusterReferencesCount);
    std::vector<std::pair<uint64_t, uint32_t>> seen;  // (address, reference index) for 10484
    seen.reserve(info.clusterReferencesCount);
    std::vector<std::pair<uint64_t, uint64_t>> read_ranges;
    read_ranges.reserve(info.clusterReferencesCount);
    for (uint32_t k = 0; k < info.clusterReferencesCount; ++k) {
        uint64_t address;
        std::memcpy(&address, refs.data() + uint64_t(k) * info.clusterReferencesStride, 8);
        seen.push_back({address, k});
        ObjectLookup clas = cmd.directory->lookup(memory, address, ObjectType::kTriangleCluster,
                                                  false, {refs_field.c_str(), i});
        if (!clas.found()) {
            rec.finding(kRuleStaleClusterReference,
                        refs_field + "[" + std::to_string(k) + "] (op " + std::to_string(i) +
                            "): " + clas.error,
                        address);
            continue;
        }
        read_ranges.push_back({address, address + clas.bytes.size()});
        ObjectHeader h;
        std::memcpy(&h, clas.bytes.data(), sizeof h);
        ClusterBox box;
        std::memcpy(box.bounds_min, h.bounds_min, sizeof box.bounds_min);
        std::memcpy(box.bounds_max, h.bounds_max, sizeof box.bounds_max);
        box.clas_address = address;
        box.reference_index = k;
        box.cluster_id = h.cluster_id;
        boxes.push_back(box);
    }
    record_cluster_reads(rec, i, read_ranges);
    std::sort(seen.begin(), seen.end());
    for (size_t k = 1; k < seen.size(); ++k) {
        if (seen[k].first == seen[k - 1].first)
            rec.finding(
                "VUID-VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV-"
                "clusterReferences-10484",
                refs_field + "[" + std::to_string(seen[k - 1].second) + "] and [" +
                    std::to_string(seen[k].second) + "] both reference " + hex(seen[k].first) +
                    " (op " + std::to_string(i) + ")",
                seen[k].first);
    }
    out.bytes = build_bottom_level(boxes, info.clusterReferencesCount);
    if (out.bytes.empty()) {
        rec.finding(kRuleBottomLevelTooLarge,
                    field(i) + ": a BLAS over " + std::to_string(boxes.size()) +
                        " clusters would exceed the 4 GiB object size limit");
        return;
    }
    out.ok = true;
}

void run_move(const ResolvedCommand& cmd, const MemoryImage& memory, uint32_t i,
              uint64_t info_address, OpOutput& out) {
    Recorder& rec = out.rec;
    FieldName f = field(i, "srcAccelerationStructure");
    auto info =
        memory.read<VkClusterAccelerationStructureMoveObjectsInfoNV>(info_address, {f.c_str(), i});
    const auto& in = *cmd.input->opInput.pMoveObjects;
    ObjectLookup obj = cmd.directory->lookup(memory, info.srcAccelerationStructure,
                                             ObjectType::kTriangleCluster, true, {f.c_str(), i});
    if (!obj.found()) {
        rec.finding(
            "VUID-VkClusterAccelerationStructureMoveObjectsInfoNV-srcAccelerationStructure-10483",
            f + " = " + hex(info.srcAccelerationStructure) + " (op " + std::to_string(i) +
                "): " + obj.error,
            info.srcAccelerationStructure);
        return;
    }
    rec.access(info.srcAccelerationStructure, obj.bytes.size(), kAccessObjectRead, false, f);
    const ObjectType moved_type = object_type_of(common::enum_bits(in.type));
    if (obj.type != moved_type) {
        rec.finding(kRuleMoveTypeMismatch,
                    f + " = " + hex(info.srcAccelerationStructure) + " holds a " +
                        object_type_name(obj.type) + " but the move input's type is " +
                        object_type_name(moved_type) + " (op " + std::to_string(i) + ")",
                    info.srcAccelerationStructure);
        return;
    }
    out.type = obj.type;
    out.bytes.assign(obj.bytes.begin(), obj.bytes.end());
    out.move_src = info.srcAccelerationStructure;
    out.move_src_size = obj.bytes.size();
    out.ok = true;
}

// `f`: field(i), which run_op has named already.
void run_cluster_op(const ResolvedCommand& cmd, const MemoryImage& memory, uint32_t i,
                    const FieldName& f, uint64_t info_address, ClusterBuilder& builder,
                    OpOutput& out) {
    Recorder& rec = out.rec;
    const auto& in = *cmd.input->opInput.pTriangleClusters;
    FieldRef where{f.c_str(), i};
    switch (cmd.op_type) {
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV: {
        auto info =
            memory.read<VkClusterAccelerationStructureBuildTriangleClusterInfoNV>(info_address,
                                                                                  where);
        record_triangle_inputs(rec, info, in, i);
        out.triangles = info.triangleCount;
        out.vertices = info.vertexCount;
        out.type = ObjectType::kTriangleCluster;
        out.ok = builder.build_triangle_cluster(memory, info, in, i, out.bytes, rec.findings);
        break;
    }
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_TEMPLATE_NV: {
        auto info = memory.read<VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV>(
            info_address, where);
        record_triangle_inputs(rec, info, in, i);
        if (info.instantiationBoundingBoxLimit != 0)
            rec.access(info.instantiationBoundingBoxLimit, 24, kAccessPointedInput, false,
                       field(i, "instantiationBoundingBoxLimit"));
        out.triangles = info.triangleCount;
        out.vertices = info.vertexCount;
        out.type = ObjectType::kTriangleClusterTemplate;
        out.ok =
            builder.build_triangle_cluster_template(memory, info, in, i, out.bytes, rec.findings);
        break;
    }
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_INSTANTIATE_TRIANGLE_CLUSTER_NV: {
        auto info =
            memory.read<VkClusterAccelerationStructureInstantiateClusterInfoNV>(info_address,
                                                                                where);
        FieldName tf = field(i, "clusterTemplateAddress");
        ObjectLookup tmpl =
            cmd.directory->lookup(memory, info.clusterTemplateAddress,
                                  ObjectType::kTriangleClusterTemplate, false, {tf.c_str(), i});
        out.type = ObjectType::kTriangleCluster;
        if (!tmpl.found()) {
            rec.finding(kRuleNotATemplate, tf + " (op " + std::to_string(i) + "): " + tmpl.error,
                        info.clusterTemplateAddress);
            return;
        }
        rec.access(info.clusterTemplateAddress, tmpl.bytes.size(), kAccessObjectRead, false, tf);
        ObjectHeader h;
        std::memcpy(&h, tmpl.bytes.data(), sizeof h);
        record_buffer(rec, info.vertexBuffer.startAddress, h.vertex_count,
                      info.vertexBuffer.strideInBytes, vertex_bytes(in), i, "vertexBuffer");
        out.triangles = h.triangle_count;
        out.vertices = h.vertex_count;
        out.ok = builder.instantiate_triangle_cluster(memory, info, in, i, out.bytes, rec.findings);
        break;
    }
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_GET_CLUSTER_TEMPLATE_INDICES_NV: {
        auto info =
            memory.read<VkClusterAccelerationStructureGetTemplateIndicesInfoNV>(info_address,
                                                                                where);
        FieldName tf = field(i, "clusterTemplateAddress");
        ObjectLookup tmpl =
            cmd.directory->lookup(memory, info.clusterTemplateAddress,
                                  ObjectType::kTriangleClusterTemplate, false, {tf.c_str(), i});
        out.is_object = false;
        if (!tmpl.found()) {
            rec.finding(kRuleNotATemplate, tf + " (op " + std::to_string(i) + "): " + tmpl.error,
                        info.clusterTemplateAddress);
            return;
        }
        rec.access(info.clusterTemplateAddress, tmpl.bytes.size(), kAccessObjectRead, false, tf);
        ClusterObject r = get_cluster_template_indices(memory, info, i);
        out.bytes = std::move(r.bytes);
        for (auto& fd : r.findings) rec.findings.push_back(std::move(fd));
        out.ok = r.ok;
        break;
    }
    default: break;
    }
    if (!out.ok) out.bytes.clear();
}

}  // namespace

void run_op(const ResolvedCommand& cmd, const MemoryImage& memory, uint32_t i,
            ClusterBuilder& builder, OpOutput& out) {
    out.rec.op_index = i;
    // An op records its info, its inputs and its destination entries (about 6 ranges): room
    // for them at once instead of the vector's 1, 2, 4, 8 growth.
    out.rec.accesses.reserve(kAccessesPerOp);
    FieldName f = field(i);
    try {
        uint64_t info_address =
            MemoryImage::strided_address(cmd.src_infos, i, cmd.info_size, {f.c_str(), i});
        out.rec.access(info_address, cmd.info_size, kAccessIndirect, false, f);
        switch (cmd.op_type) {
        case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV:
            run_move(cmd, memory, i, info_address, out);
            break;
        case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV:
            run_bottom_level(cmd, memory, i, info_address, out);
            break;
        default: run_cluster_op(cmd, memory, i, f, info_address, builder, out); break;
        }
        if (out.ok &&
            cmd.op_mode == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_EXPLICIT_DESTINATIONS_NV) {
            FieldName df("dstAddressesArray[");
            df.append_number(i).append("]");
            uint64_t a = MemoryImage::strided_address(cmd.dst_addresses, i, 8, {df.c_str(), i});
            out.explicit_dst = memory.read<uint64_t>(a, {df.c_str(), i});
            out.rec.access(a, 8, kAccessObjectWrite, false, df);
            if (cmd.dst_sizes.deviceAddress != 0) {
                FieldName sf("dstSizesArray[");
                sf.append_number(i).append("]");
                uint64_t s = MemoryImage::strided_address(cmd.dst_sizes, i, 4, {sf.c_str(), i});
                uint32_t given = memory.read<uint32_t>(s, {sf.c_str(), i});
                out.rec.access(s, 4, kAccessObjectWrite, false, sf);
                if (out.bytes.size() > given)
                    out.rec.finding(kRuleDestinationTooSmall,
                                    sf + " = " + std::to_string(given) + " bytes, but op " +
                                        std::to_string(i) + "'s object takes " +
                                        std::to_string(out.bytes.size()),
                                    out.explicit_dst);
            }
        }
    } catch (const MemoryFault& fault) {
        out.rec.fault(fault);
        out.ok = false;
        out.bytes.clear();
    } catch (const std::bad_alloc&) {
        out.rec.finding(kRuleMemoryFault, f + ": the op needs more host memory than is available");
        out.ok = false;
        out.bytes.clear();
    }
}

}  // namespace clastrace::engine::detail
