// SPDX-License-Identifier: Apache-2.0
#include "clastrace/engine/build_sizes.h"

#include "clastrace/engine/blas.h"
#include "clastrace/engine/cluster_build.h"
#include "clastrace/common/enum_bits.h"

#include <algorithm>
#include <limits>
#include <string>

namespace clastrace::engine {

using common::enum_bits;

uint64_t sat_add(uint64_t a, uint64_t b) {
    uint64_t r;
    return __builtin_add_overflow(a, b, &r) ? std::numeric_limits<uint64_t>::max() : r;
}
uint64_t sat_mul(uint64_t a, uint64_t b) {
    uint64_t r;
    return __builtin_mul_overflow(a, b, &r) ? std::numeric_limits<uint64_t>::max() : r;
}
uint64_t align_up_sat(uint64_t v, uint64_t alignment) {
    if (alignment <= 1) return v;
    uint64_t r = sat_add(v, alignment - 1);
    return r == std::numeric_limits<uint64_t>::max() ? r : r / alignment * alignment;
}

uint64_t scratch_bytes_for_ops(uint64_t op_count) { return sat_mul(op_count, 16); }

namespace {
uint64_t alignment_for(uint32_t op_type, uint32_t move_type, const EngineProperties& p) {
    auto by_type = [&](uint32_t t) -> uint64_t {
        switch (t) {
        case VK_CLUSTER_ACCELERATION_STRUCTURE_TYPE_CLUSTERS_BOTTOM_LEVEL_NV:
            return p.cluster_bottom_level_byte_alignment;
        case VK_CLUSTER_ACCELERATION_STRUCTURE_TYPE_TRIANGLE_CLUSTER_NV:
            return p.cluster_byte_alignment;
        case VK_CLUSTER_ACCELERATION_STRUCTURE_TYPE_TRIANGLE_CLUSTER_TEMPLATE_NV:
            return p.cluster_template_byte_alignment;
        default: return 1;
        }
    };
    switch (op_type) {
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV:
        return std::max<uint64_t>(1, by_type(move_type));
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV:
        return p.cluster_bottom_level_byte_alignment;
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV:
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_INSTANTIATE_TRIANGLE_CLUSTER_NV:
        return p.cluster_byte_alignment;
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_TEMPLATE_NV:
        return p.cluster_template_byte_alignment;
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_GET_CLUSTER_TEMPLATE_INDICES_NV:
        return 4;  // uint32 indices
    default: return 1;
    }
}
}  // namespace

// A captured properties struct may hold 0 (or a non power of two): never divide by 0.
uint64_t destination_alignment(uint32_t op_type, uint32_t move_type, const EngineProperties& p) {
    return std::max<uint64_t>(1, alignment_for(op_type, move_type, p));
}

namespace {

// Sum of the objects of `count` clusters whose triangles and vertices add up to at most
// the input's totals. The per-object size is probed from max_cluster_object_size as an affine
// worst case c + a*T + b*V (checked on a grid; if the format ever stops being affine
// the per-object bound times count is used alone).
uint64_t clusters_total_bound(uint64_t count,
                              const VkClusterAccelerationStructureTriangleClusterInputNV& in,
                              const EngineProperties& p, bool is_template) {
    const uint64_t one = max_cluster_object_size(in, p, is_template);
    const uint64_t per_object_total = sat_mul(count, one);
    auto f = [&](uint32_t t, uint32_t v) {
        VkClusterAccelerationStructureTriangleClusterInputNV q = in;
        q.maxClusterTriangleCount = t;
        q.maxClusterVertexCount = v;
        return max_cluster_object_size(q, p, is_template);
    };
    const uint32_t max_t =
        std::min<uint32_t>(in.maxClusterTriangleCount, EngineProperties::kFormatMaxTriangles);
    const uint32_t max_v =
        std::min<uint32_t>(in.maxClusterVertexCount, EngineProperties::kFormatMaxVertices);
    const uint64_t c = f(0, 0) + 8;  // + rounding slack
    uint64_t a = 0, b = 0;
    for (uint32_t t = 1; t <= max_t; ++t) a = std::max(a, (f(t, 0) - f(0, 0) + t - 1) / t);
    for (uint32_t v = 1; v <= max_v; ++v) b = std::max(b, (f(0, v) - f(0, 0) + v - 1) / v);
    for (uint32_t t = 0; t <= max_t; t += std::max<uint32_t>(1, max_t / 16))
        for (uint32_t v = 0; v <= max_v; v += std::max<uint32_t>(1, max_v / 16))
            if (f(t, v) > c + a * t + b * v) return per_object_total;
    const uint64_t tris = std::min<uint64_t>(in.maxTotalTriangleCount, sat_mul(count, max_t));
    const uint64_t verts = std::min<uint64_t>(in.maxTotalVertexCount, sat_mul(count, max_v));
    return std::min(per_object_total,
                    sat_add(sat_mul(count, c), sat_add(sat_mul(a, tris), sat_mul(b, verts))));
}

// The alignment of the objects `info` writes; by the op type's and the move input's bits, which
// nothing has checked yet (common/enum_bits.h).
uint64_t input_alignment(const VkClusterAccelerationStructureInputInfoNV& info,
                         const EngineProperties& p) {
    const uint32_t op_type = enum_bits(info.opType);
    const auto* move = info.opInput.pMoveObjects;
    return destination_alignment(
        op_type,
        op_type == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV && move
            ? enum_bits(move->type)
            : uint32_t(VK_CLUSTER_ACCELERATION_STRUCTURE_TYPE_MAX_ENUM_NV),
        p);
}

}  // namespace

BuildSizes cluster_build_sizes(const VkClusterAccelerationStructureInputInfoNV& info,
                               const EngineProperties& p) {
    BuildSizes s;
    const uint64_t count = info.maxAccelerationStructureCount;
    auto bad = [&](const char* rule, const std::string& msg) {
        s.findings.push_back(
            {rule, "vkGetClusterAccelerationStructureBuildSizesNV: " + msg, -1, 0});
        return s;
    };
    // Op type and mode by their bits until checked (common/enum_bits.h).
    const uint32_t op_type = enum_bits(info.opType);
    const uint32_t op_mode = enum_bits(info.opMode);
    if (op_mode > VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_COMPUTE_SIZES_NV)
        return bad("VUID-VkClusterAccelerationStructureInputInfoNV-opMode-parameter",
                   "opMode " + std::to_string(int(op_mode)) +
                       " is not a VkClusterAccelerationStructureOpModeNV");
    uint64_t one = 0;       // worst single object
    uint64_t implicit = 0;  // worst implicit total, before per-object alignment padding
    uint64_t align = input_alignment(info, p);
    switch (op_type) {
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV: {
        if (!info.opInput.pMoveObjects)
            return bad("VUID-VkClusterAccelerationStructureInputInfoNV-pMoveObjects-parameter",
                       "opInput.pMoveObjects is null");
        one = info.opInput.pMoveObjects->maxMovedBytes;
        implicit = info.opInput.pMoveObjects->maxMovedBytes;  // the moved objects together
        break;
    }
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV: {
        const auto* in = info.opInput.pClustersBottomLevel;
        if (!in)
            return bad(
                "VUID-VkClusterAccelerationStructureInputInfoNV-pClustersBottomLevel-parameter",
                "opInput.pClustersBottomLevel is null");
        uint64_t per = std::min<uint64_t>(in->maxClusterCountPerAccelerationStructure,
                                          in->maxTotalClusterCount);
        one = bottom_level_size_bound(per);
        // Each BLAS costs its header plus 80 bytes per cluster at most; clusters are shared
        // out of maxTotalClusterCount.
        uint64_t per_cluster = 2 * sizeof(BottomLevelNode) + sizeof(ClusterReference);
        implicit =
            std::min(sat_mul(count, one), sat_add(sat_mul(count, sizeof(BottomLevelHeader)),
                                                  sat_mul(in->maxTotalClusterCount, per_cluster)));
        break;
    }
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV:
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_TEMPLATE_NV:
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_INSTANTIATE_TRIANGLE_CLUSTER_NV:
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_GET_CLUSTER_TEMPLATE_INDICES_NV: {
        const auto* in = info.opInput.pTriangleClusters;
        if (!in)
            return bad("VUID-VkClusterAccelerationStructureInputInfoNV-pTriangleClusters-parameter",
                       "opInput.pTriangleClusters is null");
        if (info.opType ==
            VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_GET_CLUSTER_TEMPLATE_INDICES_NV) {
            uint64_t tris = std::min<uint64_t>(in->maxClusterTriangleCount,
                                               EngineProperties::kFormatMaxTriangles);
            one = 12 * tris;
            implicit = std::min(sat_mul(count, one), sat_mul(12, in->maxTotalTriangleCount));
        } else {
            bool is_template =
                info.opType ==
                VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_TEMPLATE_NV;
            one = max_cluster_object_size(*in, p, is_template);
            implicit = clusters_total_bound(count, *in, p, is_template);
        }
        break;
    }
    default:
        return bad("VUID-VkClusterAccelerationStructureInputInfoNV-opType-parameter",
                   "opType " + std::to_string(int(op_type)) +
                       " is not a VkClusterAccelerationStructureOpTypeNV");
    }
    s.single_object_size = one;
    // Implicit packing pads each object to `align`: at most align - 1 bytes each, and the
    // base itself is required aligned.
    uint64_t implicit_total = sat_add(implicit, sat_mul(count, align - 1));
    s.build_scratch_size = scratch_bytes_for_ops(count);
    switch (info.opMode) {
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV:
        s.acceleration_structure_size = implicit_total;
        break;
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_EXPLICIT_DESTINATIONS_NV:
        s.acceleration_structure_size = one;
        break;
    default: s.acceleration_structure_size = 0; break;
    }
    return s;
}

}  // namespace clastrace::engine
