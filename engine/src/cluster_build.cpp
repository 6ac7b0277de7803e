// SPDX-License-Identifier: Apache-2.0
// The cluster ops: read an info struct's buffers through the MemoryImage, check the
// spec's per-info rules (findings carry the VUID strings verbatim), decode and
// truncate positions, and hand the result to the encoder.
#include "clastrace/engine/cluster_build.h"
#include "clastrace/common/enum_bits.h"
#include "clastrace/common/hex.h"

#include "clastrace/engine/cluster_format.h"
#include "clastrace/engine/vertex_format.h"
#include "cluster_internal.h"

#include <algorithm>
#include <bit>
#include <cinttypes>
#include <cstdio>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

namespace clastrace::engine {

using detail::kMaxTriangles;
using detail::kMaxVertices;

struct ClusterBuilder::Scratch {
    float positions[kMaxVertices * 3];
    uint8_t index_bytes[kMaxTriangles * 3 + 1];  // EncodeInput::index_bytes
    uint8_t inactive[kMaxTriangles];
    uint32_t geometry[kMaxTriangles];
    int32_t omm[kMaxTriangles];
    detail::EncodeScratch encode;
};

ClusterBuilder::ClusterBuilder(const EngineProperties& properties)
    : properties_(properties), scratch_(std::make_unique<Scratch>()) {}
ClusterBuilder::~ClusterBuilder() = default;
ClusterBuilder::ClusterBuilder(ClusterBuilder&&) noexcept = default;
ClusterBuilder& ClusterBuilder::operator=(ClusterBuilder&&) noexcept = default;

namespace {

using common::hex;

// Collects findings for one op with the op's context in every message.
struct Reporter {
    std::vector<Finding>& out;
    int64_t op_index;
    const char* info_name;
    void add(const char* rule, const std::string& what, uint64_t address = 0) {
        out.push_back(Finding{rule,
                              std::string(info_name) + ": " + what + " (op " +
                                  std::to_string(op_index) +
                                  (address ? ", address " + hex(address) : std::string()) + ")",
                              op_index, address});
    }
};

// The cluster template at `address`, read whole by the size its header gives. No header (and
// kRuleNotATemplate reported) when the address holds something else.
struct TemplateRead {
    std::span<const std::byte> bytes;
    std::optional<ObjectHeader> header;
};
TemplateRead read_cluster_template(const MemoryImage& memory, uint64_t address, int64_t op_index,
                                   Reporter& r) {
    const auto head =
        memory.read_bytes(address, sizeof(ObjectHeader), {"clusterTemplateAddress", op_index});
    const uint32_t size = object_size_from_header(head);
    TemplateRead t{memory.read_bytes(address, size ? size : sizeof(ObjectHeader),
                                     {"clusterTemplateAddress", op_index}),
                   {}};
    HeaderCheck hc = read_object_header(t.bytes);
    if (!hc.header || hc.header->object_type != uint8_t(ObjectType::kTriangleClusterTemplate)) {
        r.add(kRuleNotATemplate,
              "clusterTemplateAddress holds no cluster template: " +
                  (hc.header ? std::string("object is a CLAS") : hc.error),
              address);
        return t;
    }
    t.header = hc.header;
    return t;
}

// The fields the build and the template info share (same layout up to offset 64).
struct TriangleInfoView {
    uint32_t cluster_id, cluster_flags, triangle_count, vertex_count, position_truncate_bit_count,
        index_type, opacity_micromap_index_type;
    uint32_t base_geometry_index_and_flags;
    uint16_t index_buffer_stride, vertex_buffer_stride, geometry_index_and_flags_buffer_stride,
        opacity_micromap_index_buffer_stride;
    uint64_t index_buffer, vertex_buffer, geometry_index_and_flags_buffer, opacity_micromap_array,
        opacity_micromap_index_buffer;
};

template <class Info>
TriangleInfoView view_of(const Info& i) {
    TriangleInfoView v;
    v.cluster_id = i.clusterID;
    v.cluster_flags = i.clusterFlags;
    v.triangle_count = i.triangleCount;
    v.vertex_count = i.vertexCount;
    v.position_truncate_bit_count = i.positionTruncateBitCount;
    v.index_type = i.indexType;
    v.opacity_micromap_index_type = i.opacityMicromapIndexType;
    std::memcpy(&v.base_geometry_index_and_flags, &i.baseGeometryIndexAndGeometryFlags, 4);
    v.index_buffer_stride = i.indexBufferStride;
    v.vertex_buffer_stride = i.vertexBufferStride;
    v.geometry_index_and_flags_buffer_stride = i.geometryIndexAndFlagsBufferStride;
    v.opacity_micromap_index_buffer_stride = i.opacityMicromapIndexBufferStride;
    v.index_buffer = i.indexBuffer;
    v.vertex_buffer = i.vertexBuffer;
    v.geometry_index_and_flags_buffer = i.geometryIndexAndFlagsBuffer;
    v.opacity_micromap_array = i.opacityMicromapArray;
    v.opacity_micromap_index_buffer = i.opacityMicromapIndexBuffer;
    return v;
}

// The VUID strings of one info struct: the build and the template info carry the same
// rules under different numbers.
struct InfoRules {
    const char* name;
    const char* cluster_id;
    const char* triangle_count;
    const char* vertex_count;
    const char* index_type;
    const char* opacity_micromap_index_type;
    const char* position_truncate_bit_count;
    const char* index_buffer_stride;
    const char* vertex_buffer_stride;
    const char* base_geometry_index;
    const char* cluster_flags;
};

constexpr InfoRules kBuildRules{
    "VkClusterAccelerationStructureBuildTriangleClusterInfoNV",
    "VUID-VkClusterAccelerationStructureBuildTriangleClusterInfoNV-clusterID-10488",
    "VUID-VkClusterAccelerationStructureBuildTriangleClusterInfoNV-triangleCount-10489",
    "VUID-VkClusterAccelerationStructureBuildTriangleClusterInfoNV-vertexCount-10490",
    "VUID-VkClusterAccelerationStructureBuildTriangleClusterInfoNV-indexType-10491",
    "VUID-VkClusterAccelerationStructureBuildTriangleClusterInfoNV-opacityMicromapIndexType-10492",
    "VUID-VkClusterAccelerationStructureBuildTriangleClusterInfoNV-positionTruncateBitCount-10493",
    "VUID-VkClusterAccelerationStructureBuildTriangleClusterInfoNV-indexBufferStride-10494",
    "VUID-VkClusterAccelerationStructureBuildTriangleClusterInfoNV-vertexBufferStride-10495",
    "VUID-VkClusterAccelerationStructureBuildTriangleClusterInfoNV-baseGeometryIndex-10496",
    "VUID-VkClusterAccelerationStructureBuildTriangleClusterInfoNV-clusterFlags-parameter",
};

constexpr InfoRules kTemplateRules{
    "VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV",
    "VUID-VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV-clusterID-10497",
    "VUID-VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV-triangleCount-10498",
    "VUID-VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV-vertexCount-10499",
    "VUID-VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV-indexType-10500",
    "VUID-VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV-"
    "opacityMicromapIndexType-10501",
    "VUID-VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV-"
    "positionTruncateBitCount-10502",
    "VUID-VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV-indexBufferStride-10503",
    "VUID-VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV-vertexBufferStride-"
    "10504",
    "VUID-VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV-baseGeometryIndex-10506",
    "VUID-VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV-clusterFlags-parameter",
};

bool single_bit(uint32_t v) { return v != 0 && (v & (v - 1)) == 0; }

// Rules on the TriangleClusterInput itself (checked with every op that uses it).
void check_input(const VkClusterAccelerationStructureTriangleClusterInputNV& input,
                 const EngineProperties& p, Reporter& r) {
    // By its bits until found supported (common/enum_bits.h).
    const uint32_t format = common::enum_bits(input.vertexFormat);
    if (!vertex_format_info(format).supported)
        r.add("VUID-VkClusterAccelerationStructureTriangleClusterInputNV-vertexFormat-10439",
              "vertexFormat " + std::to_string(int(format)) +
                  " lacks VK_FORMAT_FEATURE_ACCELERATION_STRUCTURE_VERTEX_BUFFER_BIT_KHR");
    if (input.maxClusterTriangleCount > p.max_triangles_per_cluster)
        r.add(
            "VUID-VkClusterAccelerationStructureTriangleClusterInputNV-maxClusterTriangleCount-"
            "10440",
            "maxClusterTriangleCount " + std::to_string(input.maxClusterTriangleCount) +
                " > maxTrianglesPerCluster " + std::to_string(p.max_triangles_per_cluster));
    if (input.maxClusterVertexCount > p.max_vertices_per_cluster)
        r.add(
            "VUID-VkClusterAccelerationStructureTriangleClusterInputNV-maxClusterVertexCount-10441",
            "maxClusterVertexCount " + std::to_string(input.maxClusterVertexCount) +
                " > maxVerticesPerCluster " + std::to_string(p.max_vertices_per_cluster));
    if (input.minPositionTruncateBitCount > 32)
        r.add(
            "VUID-VkClusterAccelerationStructureTriangleClusterInputNV-minPositionTruncateBitCount-"
            "10442",
            "minPositionTruncateBitCount " + std::to_string(input.minPositionTruncateBitCount) +
                " > 32");
}

struct Decoded {
    uint32_t triangle_count = 0, vertex_count = 0, truncate_bits = 0;
    bool has_positions = false, has_geometry = false, has_omm = false;
    // Some triangle has an index out of range (its flag set in the inactive array). A build
    // then hands the encoder no flags at all: its scan for a set flag, with wide loads over
    // the flags' stores just made, would wait for them to reach the cache.
    bool any_inactive = false;
    uint32_t omm_index_type = 0;
    // The decoded positions: the scratch's, or the vertex buffer itself when it holds them as
    // the object does (packed 32-bit floats, untruncated), which then needs no copy.
    const float* positions = nullptr;
};

// One decode: what it reads, the rules it checks it by, and where it writes (the builder's
// scratch arrays, sized for kMaxVertices / kMaxTriangles).
struct TriangleDecode {
    const MemoryImage& memory;
    const TriangleInfoView& info;
    const VkClusterAccelerationStructureTriangleClusterInputNV& input;
    const EngineProperties& properties;
    const InfoRules& rules;
    bool positions_optional;  // a template may leave vertexBuffer 0
    float* positions;
    uint8_t* index_bytes;
    uint8_t* inactive;
    uint32_t* geometry;
    int32_t* omm;
    Decoded& decoded;
    Reporter& report;
};

// Bytes of one index of a VkClusterAccelerationStructureIndexFormatFlagBitsNV value (1
// for a value that is none, which the checks report).
uint32_t index_size_of(uint32_t index_type) {
    return single_bit(index_type) && index_type <= 4 ? index_type : 1;
}

// The info's counts, flags, formats and strides against the properties and the input.
// Returns false when no object can be built.
bool check_triangle_info(const TriangleDecode& job, const VertexFormatInfo& vf) {
    const TriangleInfoView& info = job.info;
    const VkClusterAccelerationStructureTriangleClusterInputNV& input = job.input;
    const EngineProperties& p = job.properties;
    const InfoRules& rules = job.rules;
    Reporter& r = job.report;
    bool buildable = vf.supported;
    if (info.cluster_id == 0xFFFFFFFFu) r.add(rules.cluster_id, "clusterID is 0xFFFFFFFF");
    if (info.cluster_flags &
        ~uint32_t(VK_CLUSTER_ACCELERATION_STRUCTURE_CLUSTER_ALLOW_DISABLE_OPACITY_MICROMAPS_NV))
        r.add(rules.cluster_flags,
              "clusterFlags " + hex(info.cluster_flags) +
                  " has bits no VkClusterAccelerationStructureClusterFlagBitsNV defines");
    if (info.triangle_count > p.max_triangles_per_cluster)
        r.add(rules.triangle_count, "triangleCount " + std::to_string(info.triangle_count) +
                                        " > maxTrianglesPerCluster " +
                                        std::to_string(p.max_triangles_per_cluster));
    if (info.vertex_count > p.max_vertices_per_cluster)
        r.add(rules.vertex_count, "vertexCount " + std::to_string(info.vertex_count) +
                                      " > maxVerticesPerCluster " +
                                      std::to_string(p.max_vertices_per_cluster));
    if (info.triangle_count > kMaxTriangles || info.vertex_count > kMaxVertices) {
        r.add(kRuleBeyondEngineFormat, "triangleCount " + std::to_string(info.triangle_count) +
                                           " / vertexCount " + std::to_string(info.vertex_count) +
                                           " exceed the engine's 256 per cluster");
        buildable = false;
    }
    if (info.triangle_count > input.maxClusterTriangleCount)
        r.add(kRuleCountAboveInput,
              "triangleCount " + std::to_string(info.triangle_count) +
                  " > "
                  "VkClusterAccelerationStructureTriangleClusterInputNV::maxClusterTriangleCount " +
                  std::to_string(input.maxClusterTriangleCount));
    if (info.vertex_count > input.maxClusterVertexCount)
        r.add(
            kRuleCountAboveInput,
            "vertexCount " + std::to_string(info.vertex_count) +
                " > VkClusterAccelerationStructureTriangleClusterInputNV::maxClusterVertexCount " +
                std::to_string(input.maxClusterVertexCount));
    if (!single_bit(info.index_type)) {
        r.add(rules.index_type, "indexType " + std::to_string(info.index_type) +
                                    " does not have exactly one bit set");
        buildable = false;
    } else if (info.index_type > 4) {
        r.add(rules.index_type, "indexType " + std::to_string(info.index_type) +
                                    " is no VkClusterAccelerationStructureIndexFormatFlagBitsNV");
        buildable = false;
    }
    const bool uses_omm =
        info.opacity_micromap_array != 0 || info.opacity_micromap_index_buffer != 0;
    if (uses_omm && !single_bit(info.opacity_micromap_index_type))
        r.add(rules.opacity_micromap_index_type,
              "opacityMicromapIndexType " + std::to_string(info.opacity_micromap_index_type) +
                  " does not have exactly one bit set");
    if (info.position_truncate_bit_count < input.minPositionTruncateBitCount ||
        info.position_truncate_bit_count > 32)
        r.add(rules.position_truncate_bit_count,
              "positionTruncateBitCount " + std::to_string(info.position_truncate_bit_count) +
                  " outside [minPositionTruncateBitCount " +
                  std::to_string(input.minPositionTruncateBitCount) + ", 32]");
    const uint32_t index_size = index_size_of(info.index_type);
    if (info.index_buffer_stride % index_size != 0)
        r.add(rules.index_buffer_stride,
              "indexBufferStride " + std::to_string(info.index_buffer_stride) +
                  " is not 0 or a multiple of " + std::to_string(index_size));
    if (vf.supported && info.vertex_buffer_stride % vf.component_size != 0)
        r.add(rules.vertex_buffer_stride,
              "vertexBufferStride " + std::to_string(info.vertex_buffer_stride) +
                  " is not 0 or a multiple of the vertex format's component size " +
                  std::to_string(vf.component_size));
    return buildable;
}

// Packed 8-bit indices (the usual cluster index buffer) copied as they are, with their
// largest value found 16 at a time where the target has SSE2 (GCC at -O2 vectorizes no
// maximum of bytes). An empty cluster's indices are an empty span, whose data() is null, which
// memcpy may not be given even for 0 bytes.
uint32_t copy_packed_bytes(const std::byte* src, uint32_t count, uint8_t* dst) {
    if (count != 0) std::memcpy(dst, src, count);
    uint32_t i = 0, largest = 0;
#if defined(__SSE2__)
    __m128i top = _mm_setzero_si128();
    for (; i + 16 <= count; i += 16)
        top = _mm_max_epu8(top, _mm_loadu_si128(reinterpret_cast<const __m128i*>(src + i)));
    top = _mm_max_epu8(top, _mm_srli_si128(top, 8));
    top = _mm_max_epu8(top, _mm_srli_si128(top, 4));
    top = _mm_max_epu8(top, _mm_srli_si128(top, 2));
    top = _mm_max_epu8(top, _mm_srli_si128(top, 1));
    largest = uint32_t(_mm_cvtsi128_si32(top)) & 0xFFu;
#endif
    for (; i < count; ++i) largest = std::max(largest, uint32_t(dst[i]));
    return largest;
}

// Index i of a buffer of `size`-byte indices `step` bytes apart.
uint32_t index_at(const std::byte* src, uint32_t size, uint32_t step, uint32_t i) {
    uint32_t value = 0;  // little endian: the low `size` bytes
    std::memcpy(&value, src + size_t(i) * step, size);
    return value;
}

// Each index's low byte (all an object stores: the indices of an active triangle are below
// its vertex count, at most 256), then a zero byte; triangles with an index >= vertexCount
// are inactive. No 32-bit copy of the indices is kept: the rare out-of-range case rereads
// the buffer.
void decode_indices(const TriangleDecode& job) {
    const TriangleInfoView& info = job.info;
    uint8_t* const index_bytes = job.index_bytes;
    uint8_t* const inactive = job.inactive;
    Reporter& r = job.report;
    const uint32_t n_triangles = job.decoded.triangle_count, n_vertices = job.decoded.vertex_count;
    const uint32_t index_size = index_size_of(info.index_type);
    const auto idx =
        job.memory.read_array(info.index_buffer, 3ull * n_triangles, info.index_buffer_stride,
                              index_size, {"indexBuffer", r.op_index});
    const uint32_t istep = info.index_buffer_stride ? info.index_buffer_stride : index_size;
    // One loop per index size, no per-value switch.
    const std::byte* const isrc = idx.data();
    const uint32_t n_indices = 3 * n_triangles;
    uint32_t largest_index = 0;
    if (index_size == 1 && istep == 1) {
        largest_index = copy_packed_bytes(isrc, n_indices, index_bytes);
    } else if (index_size == 1) {
        for (uint32_t i = 0; i < n_indices; ++i) {
            index_bytes[i] = uint8_t(isrc[size_t(i) * istep]);
            largest_index = std::max<uint32_t>(largest_index, index_bytes[i]);
        }
    } else if (index_size == 2) {
        for (uint32_t i = 0; i < n_indices; ++i) {
            uint16_t value;
            std::memcpy(&value, isrc + size_t(i) * istep, 2);
            index_bytes[i] = uint8_t(value);
            largest_index = std::max<uint32_t>(largest_index, value);
        }
    } else {
        for (uint32_t i = 0; i < n_indices; ++i) {
            uint32_t value;
            std::memcpy(&value, isrc + size_t(i) * istep, 4);
            index_bytes[i] = uint8_t(value);
            largest_index = std::max(largest_index, value);
        }
    }
    index_bytes[n_indices] = 0;  // the last triangle's fourth byte (the encoder's 4-byte loads)
    // The common case, every index in range, costs one vectorized pass.
    if (largest_index < n_vertices) {
        std::memset(inactive, 0, n_triangles);
        return;
    }
    uint32_t out_of_range = 0, first_bad = 0;
    for (uint32_t t = 0; t < n_triangles; ++t) {
        uint32_t bad = 0;
        for (uint32_t v = 0; v < 3; ++v)
            if (index_at(isrc, index_size, istep, 3 * t + v) >= n_vertices) {
                if (out_of_range + bad == 0) first_bad = 3 * t + v;
                ++bad;
            }
        inactive[t] = bad != 0;
        out_of_range += bad;
    }
    job.decoded.any_inactive = out_of_range != 0;
    if (out_of_range == 0) return;  // no triangles
    r.add(kRuleIndexOutOfRange,
          std::to_string(out_of_range) + " index value(s) >= vertexCount " +
              std::to_string(n_vertices) + "; first at index " + std::to_string(first_bad) +
              " (value " + std::to_string(index_at(isrc, index_size, istep, first_bad)) +
              "); those triangles are inactive",
          info.index_buffer);
}

// Positions: decoded, then truncated on their 32-bit patterns.
void decode_positions(const TriangleDecode& job, const VertexFormatInfo& vf) {
    const TriangleInfoView& info = job.info;
    const VkClusterAccelerationStructureTriangleClusterInputNV& input = job.input;
    float* const positions = job.positions;
    Decoded& d = job.decoded;
    const uint32_t n_vertices = d.vertex_count;
    d.has_positions = !(job.positions_optional && info.vertex_buffer == 0);
    d.positions = positions;
    if (d.has_positions && n_vertices > 0) {
        const auto vb =
            job.memory.read_array(info.vertex_buffer, n_vertices, info.vertex_buffer_stride,
                                  vf.size, {"vertexBuffer", job.report.op_index});
        const uint32_t vstep = info.vertex_buffer_stride ? info.vertex_buffer_stride : vf.size;
        const bool packed_floats = input.vertexFormat == VK_FORMAT_R32G32B32_SFLOAT && vstep == 12;
        if (packed_floats && d.truncate_bits == 0 &&
            reinterpret_cast<uintptr_t>(vb.data()) % alignof(float) == 0) {
            d.positions = reinterpret_cast<const float*>(vb.data());
            return;
        }
        if (packed_floats) {
            std::memcpy(positions, vb.data(), size_t(n_vertices) * 12);
        } else if (input.vertexFormat == VK_FORMAT_R32G32B32_SFLOAT ||
                   input.vertexFormat == VK_FORMAT_R32G32B32A32_SFLOAT) {
            for (uint32_t v = 0; v < n_vertices; ++v)
                std::memcpy(positions + 3 * v, vb.data() + size_t(v) * vstep, 12);
        } else {
            for (uint32_t v = 0; v < n_vertices; ++v)
                decode_vertex(input.vertexFormat, vb.data() + size_t(v) * vstep, positions + 3 * v);
        }
        if (d.truncate_bits) {
            const uint32_t mask = d.truncate_bits >= 32 ? 0u : ~((1u << d.truncate_bits) - 1u);
            for (uint32_t c = 0; c < 3 * n_vertices; ++c)
                positions[c] = std::bit_cast<float>(std::bit_cast<uint32_t>(positions[c]) & mask);
        }
    }
}

// Geometry index and flags: base + per-triangle index; flags of both.
void decode_geometry_indices(const TriangleDecode& job) {
    const TriangleInfoView& info = job.info;
    const VkClusterAccelerationStructureTriangleClusterInputNV& input = job.input;
    const EngineProperties& p = job.properties;
    const InfoRules& rules = job.rules;
    uint32_t* const geometry = job.geometry;
    Decoded& d = job.decoded;
    Reporter& r = job.report;
    const uint32_t n_triangles = d.triangle_count;
    constexpr uint32_t kReservedBits = 0x1F000000u;  // reserved:5 above geometryIndex:24
    constexpr const char* kReservedRule =
        "VUID-VkClusterAccelerationStructureGeometryIndexAndGeometryFlagsNV-reserved-10487";
    const uint32_t base = info.base_geometry_index_and_flags;
    if (base & kReservedBits)
        r.add(kReservedRule, "baseGeometryIndexAndGeometryFlags.reserved is not 0");
    uint32_t max_index = base & 0xFFFFFFu;
    d.has_geometry = info.geometry_index_and_flags_buffer != 0;
    if (d.has_geometry) {
        const auto gb = job.memory.read_array(info.geometry_index_and_flags_buffer, n_triangles,
                                              info.geometry_index_and_flags_buffer_stride, 4,
                                              {"geometryIndexAndFlagsBuffer", r.op_index});
        const uint32_t gstep = info.geometry_index_and_flags_buffer_stride
                                   ? info.geometry_index_and_flags_buffer_stride
                                   : 4;
        uint32_t unique[8];
        uint32_t n_unique = 0, reserved_set = 0;
        bool many = false;
        max_index = 0;
        for (uint32_t t = 0; t < n_triangles; ++t) {
            uint32_t g;
            std::memcpy(&g, gb.data() + size_t(t) * gstep, 4);
            reserved_set += (g & kReservedBits) != 0;
            const uint32_t index = (base & 0xFFFFFFu) + (g & 0xFFFFFFu);
            const uint32_t flags = (base | g) & 0xE0000000u;
            max_index = std::max(max_index, index);
            geometry[t] = (index & 0xFFFFFFu) | flags;
            if (!many && std::find(unique, unique + n_unique, index) == unique + n_unique) {
                if (n_unique == 8)
                    many = true;
                else
                    unique[n_unique++] = index;
            }
        }
        if (reserved_set)
            r.add(kReservedRule,
                  std::to_string(reserved_set) +
                      " geometryIndexAndFlagsBuffer entries have reserved bits set",
                  info.geometry_index_and_flags_buffer);
        if (input.maxClusterUniqueGeometryCount &&
            (many || n_unique > input.maxClusterUniqueGeometryCount))
            r.add(kRuleUniqueGeometryCount,
                  "more unique geometry indices than maxClusterUniqueGeometryCount " +
                      std::to_string(input.maxClusterUniqueGeometryCount));
    }
    if (max_index >= p.max_cluster_geometry_index)
        r.add(rules.base_geometry_index, "maximum geometry index " + std::to_string(max_index) +
                                             " is not less than maxClusterGeometryIndex " +
                                             std::to_string(p.max_cluster_geometry_index));
    if (max_index > input.maxGeometryIndexValue)
        r.add(
            kRuleGeometryIndexAboveInput,
            "maximum geometry index " + std::to_string(max_index) +
                " > VkClusterAccelerationStructureTriangleClusterInputNV::maxGeometryIndexValue " +
                std::to_string(input.maxGeometryIndexValue));
}

// Opacity micromaps: recorded (array address and per-triangle indices), not traced.
void decode_opacity_micromaps(const TriangleDecode& job) {
    const TriangleInfoView& info = job.info;
    int32_t* const omm = job.omm;
    Decoded& d = job.decoded;
    const uint32_t n_triangles = d.triangle_count;
    d.has_omm = info.opacity_micromap_array != 0;
    if (d.has_omm) {
        d.omm_index_type = info.opacity_micromap_index_type;
        const uint32_t osize =
            single_bit(info.opacity_micromap_index_type) && info.opacity_micromap_index_type <= 4
                ? info.opacity_micromap_index_type
                : 4;
        if (info.opacity_micromap_index_buffer != 0) {
            const auto ob =
                job.memory.read_array(info.opacity_micromap_index_buffer, n_triangles,
                                      info.opacity_micromap_index_buffer_stride, osize,
                                      {"opacityMicromapIndexBuffer", job.report.op_index});
            const uint32_t ostep = info.opacity_micromap_index_buffer_stride
                                       ? info.opacity_micromap_index_buffer_stride
                                       : osize;
            for (uint32_t t = 0; t < n_triangles; ++t) {
                const std::byte* src = ob.data() + size_t(t) * ostep;
                int32_t value;
                if (osize == 1)
                    value = int8_t(*src);
                else if (osize == 2) {
                    int16_t s;
                    std::memcpy(&s, src, 2);
                    value = s;
                } else
                    std::memcpy(&value, src, 4);
                omm[t] = value;
            }
        } else {
            for (uint32_t t = 0; t < n_triangles; ++t)
                omm[t] = int32_t(t);  // no index buffer: triangle i uses micromap i
        }
    }
}

// Reads and checks everything a build or template info names. Returns false when no
// object can be built; findings say why.
bool decode_triangle_info(const TriangleDecode& job) {
    check_input(job.input, job.properties, job.report);
    const VertexFormatInfo vf = vertex_format_info(common::enum_bits(job.input.vertexFormat));
    if (!check_triangle_info(job, vf)) return false;
    Decoded& d = job.decoded;
    d.triangle_count = job.info.triangle_count;
    d.vertex_count = job.info.vertex_count;
    d.truncate_bits = std::min<uint32_t>(job.info.position_truncate_bit_count, 32);
    decode_indices(job);
    decode_positions(job, vf);
    decode_geometry_indices(job);
    decode_opacity_micromaps(job);
    return true;
}

// A failed op's result: no object (the vector keeps its capacity).
bool no_object(std::vector<std::byte>& out) {
    out.clear();
    return false;
}

void report_fault(const MemoryFault& f, Reporter& r) {
    r.out.push_back(Finding{kRuleMemoryFault, std::string(r.info_name) + ": " + f.message,
                            r.op_index, f.address});
}

// The encoder fields a cluster and a template take alike from their info and its decoding;
// the caller sets the object type, positions and inactive triangles, where the two differ.
void set_shared_encode_fields(const TriangleInfoView& info,
                              const VkClusterAccelerationStructureTriangleClusterInputNV& input,
                              const Decoded& d, const uint8_t* index_bytes,
                              const uint32_t* geometry, const int32_t* omm,
                              detail::EncodeInput& in) {
    in.cluster_id = info.cluster_id;
    in.cluster_flags = info.cluster_flags;
    in.triangle_count = d.triangle_count;
    in.vertex_count = d.vertex_count;
    in.truncate_bits = d.truncate_bits;
    in.vertex_format = common::enum_bits(input.vertexFormat);
    in.index_bytes = index_bytes;
    in.base_geometry_index_and_flags = info.base_geometry_index_and_flags;
    in.geometry_index_and_flags = d.has_geometry ? geometry : nullptr;
    in.has_omm = d.has_omm;
    in.omm_array = info.opacity_micromap_array;
    in.omm_index_type = d.omm_index_type;
    in.omm_indices = omm;
}

// What an instantiation checks of its info alone, before reading the template.
void check_instantiate_info(const VkClusterAccelerationStructureInstantiateClusterInfoNV& info,
                            const VkClusterAccelerationStructureTriangleClusterInputNV& input,
                            const EngineProperties& properties, Reporter& r) {
    check_input(input, properties, r);
    if (info.reserved != 0)
        r.add("VUID-VkClusterAccelerationStructureInstantiateClusterInfoNV-reserved-10509",
              "reserved is " + std::to_string(info.reserved) + ", not 0");
}

// An instantiation's inputs besides its scratch: the info, the template read and its header.
struct InstanceSource {
    const MemoryImage& memory;
    const VkClusterAccelerationStructureInstantiateClusterInfoNV& info;
    const VkClusterAccelerationStructureTriangleClusterInputNV& input;
    std::span<const std::byte> bytes;  // the template
    const ObjectHeader& h;
    int64_t op_index;
};

// The instance's vertex positions (truncated as the template's): its vertex buffer's, or the
// template's own when the buffer is 0. False when there are none to take (finding reported).
bool instance_positions(const InstanceSource& src, float* positions, Reporter& r) {
    const ObjectHeader& h = src.h;
    const auto& vertices = src.info.vertexBuffer;
    if (vertices.startAddress == 0) {
        if (!(h.header_flags & kHasPositions)) {
            r.add("VUID-VkClusterAccelerationStructureInstantiateClusterInfoNV-vertexBuffer-10507",
                  "vertexBuffer is 0 but the template was built without vertex data",
                  src.info.clusterTemplateAddress);
            return false;
        }
        for (uint32_t v = 0; v < h.vertex_count; ++v)
            decode_position(src.bytes, h, v, positions + 3 * v);
        return true;
    }
    const VertexFormatInfo vf = vertex_format_info(common::enum_bits(src.input.vertexFormat));
    if (!vf.supported) return false;  // 10439 reported by check_input
    const auto vb =
        src.memory.read_array(vertices.startAddress, h.vertex_count, vertices.strideInBytes,
                              vf.size, {"vertexBuffer", src.op_index});
    const uint64_t vstep = vertices.strideInBytes ? vertices.strideInBytes : vf.size;
    for (uint32_t v = 0; v < h.vertex_count; ++v) {
        decode_vertex(src.input.vertexFormat, vb.data() + size_t(v * vstep), positions + 3 * v);
        for (int k = 0; k < 3; ++k)
            positions[3 * v + k] =
                truncate_position(positions[3 * v + k], h.position_truncate_bits);
    }
    return true;
}

// Reports the instance's vertices outside the template's instantiationBoundingBoxLimit.
void check_bounds_limit(std::span<const std::byte> bytes, const ObjectHeader& h,
                        const float* positions, uint64_t vertex_buffer, Reporter& r) {
    float lim[6];
    std::memcpy(lim, bytes.data() + h.bounds_limit_offset, 24);
    uint32_t outside = 0, first = 0;
    for (uint32_t v = 0; v < h.vertex_count; ++v)
        for (int k = 0; k < 3; ++k) {
            const float c = positions[3 * v + k];
            if (!(c >= lim[k] && c <= lim[3 + k])) {  // NaN is outside too
                if (outside++ == 0) first = v;
                break;
            }
        }
    if (outside)
        r.add(kRuleInstanceOutsideLimit,
              std::to_string(outside) +
                  " instantiated vertex position(s) outside the template's "
                  "instantiationBoundingBoxLimit; first is vertex " +
                  std::to_string(first),
              vertex_buffer);
}

// geometryIndexOffset: a signed 24-bit value.
int32_t geometry_index_offset(const VkClusterAccelerationStructureInstantiateClusterInfoNV& info) {
    return int32_t(uint32_t(info.geometryIndexOffset) << 8) >> 8;
}

// The lowest and highest geometry index of an instance's triangles after the offset; max < min
// when it has none.
struct GeometryIndexRange {
    int64_t min = INT64_MAX, max = -1;
};

// The template's triangles back in the application's order: their local indices, their
// geometry indices and flags with the offset added, all active.
GeometryIndexRange instance_triangles(std::span<const std::byte> bytes, const ObjectHeader& h,
                                      int32_t offset, uint8_t* index_bytes, uint32_t* geometry,
                                      uint8_t* inactive) {
    GeometryIndexRange range;
    for (uint32_t i = 0; i < h.triangle_count; ++i) {
        const DecodedTriangle tri = decode_triangle(bytes, h, i);
        const uint32_t t = tri.original_index;
        for (int v = 0; v < 3; ++v) index_bytes[3 * t + v] = uint8_t(tri.local_indices[v]);
        const int64_t index = int64_t(tri.geometry_index_and_flags & 0xFFFFFFu) + offset;
        range.max = std::max(range.max, index);
        range.min = std::min(range.min, index);
        geometry[t] = (uint32_t(index) & 0xFFFFFFu) | (tri.geometry_index_and_flags & 0xE0000000u);
        inactive[t] = 0;
    }
    index_bytes[3 * h.triangle_count] = 0;  // EncodeInput's one readable byte past the indices
    return range;
}

void check_geometry_index_range(const GeometryIndexRange& range, int32_t offset,
                                const EngineProperties& properties, Reporter& r) {
    if (range.max < range.min) return;  // no triangle
    if (range.max >= int64_t(properties.max_cluster_geometry_index) || range.min < 0)
        r.add(
            "VUID-VkClusterAccelerationStructureInstantiateClusterInfoNV-geometryIndexOffset-"
            "10510",
            "geometry indices after geometryIndexOffset " + std::to_string(offset) + " span [" +
                std::to_string(range.min) + ", " + std::to_string(range.max) +
                "], not within [0, maxClusterGeometryIndex " +
                std::to_string(properties.max_cluster_geometry_index) + ")");
}

// An instance's per-vertex and per-triangle arrays, filled by the steps above.
struct InstanceArrays {
    const float* positions;
    const uint8_t* index_bytes;
    const uint8_t* inactive;
    const uint32_t* geometry;
    int32_t* omm;  // filled here from the template's OMM section, when it has one
};

// The encoder's input for an instance: the template's header fields with the info's offsets,
// the instance's arrays, and the template's OMM indices (kept in application order).
detail::EncodeInput instance_encode_input(
    std::span<const std::byte> bytes, const ObjectHeader& h,
    const VkClusterAccelerationStructureInstantiateClusterInfoNV& info, const InstanceArrays& a) {
    const uint32_t n_triangles = h.triangle_count;
    detail::EncodeInput in;
    in.type = ObjectType::kTriangleCluster;
    in.cluster_id = h.cluster_id + info.clusterIdOffset;
    in.cluster_flags = h.cluster_flags;
    in.triangle_count = n_triangles;
    in.vertex_count = h.vertex_count;
    in.truncate_bits = h.position_truncate_bits;
    in.vertex_format = h.vertex_format;
    in.positions = a.positions;
    in.index_bytes = a.index_bytes;
    in.inactive = a.inactive;
    in.base_geometry_index_and_flags =
        n_triangles ? a.geometry[0] : h.base_geometry_index_and_flags;
    in.geometry_index_and_flags = n_triangles ? a.geometry : nullptr;
    if (h.header_flags & kHasOpacityMicromap) {
        OpacityMicromapSection sec;
        std::memcpy(&sec, bytes.data() + h.omm_offset, sizeof sec);
        in.has_omm = true;
        in.omm_array = sec.opacity_micromap_array;
        in.omm_index_type = sec.index_type;
        std::memcpy(a.omm, bytes.data() + h.omm_offset + sizeof sec, 4 * size_t(n_triangles));
        in.omm_indices = a.omm;
    }
    return in;
}

}  // namespace

bool ClusterBuilder::build_triangle_cluster(
    const MemoryImage& memory, const VkClusterAccelerationStructureBuildTriangleClusterInfoNV& info,
    const VkClusterAccelerationStructureTriangleClusterInputNV& input, int64_t op_index,
    std::vector<std::byte>& out, std::vector<Finding>& findings) {
    Reporter r{findings, op_index, kBuildRules.name};
    Scratch& s = *scratch_;
    Decoded d;
    try {
        if (!decode_triangle_info({memory, view_of(info), input, properties_, kBuildRules,
                                   /*positions_optional=*/false, s.positions, s.index_bytes,
                                   s.inactive, s.geometry, s.omm, d, r}))
            return no_object(out);
    } catch (const MemoryFault& f) {
        report_fault(f, r);
        return no_object(out);
    }
    detail::EncodeInput in;
    in.type = ObjectType::kTriangleCluster;
    set_shared_encode_fields(view_of(info), input, d, s.index_bytes, s.geometry, s.omm, in);
    in.positions = d.positions;
    in.inactive = d.any_inactive ? s.inactive : nullptr;
    detail::encode_object(in, s.encode, stores_, out);
    return true;
}

bool ClusterBuilder::build_triangle_cluster_template(
    const MemoryImage& memory,
    const VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV& info,
    const VkClusterAccelerationStructureTriangleClusterInputNV& input, int64_t op_index,
    std::vector<std::byte>& out, std::vector<Finding>& findings) {
    Reporter r{findings, op_index, kTemplateRules.name};
    Scratch& s = *scratch_;
    Decoded d;
    detail::EncodeInput in;
    try {
        if (!decode_triangle_info({memory, view_of(info), input, properties_, kTemplateRules,
                                   /*positions_optional=*/true, s.positions, s.index_bytes,
                                   s.inactive, s.geometry, s.omm, d, r}))
            return no_object(out);
        for (uint32_t t = 0; t < d.triangle_count; ++t)
            if (s.inactive[t])
                return no_object(
                    out);  // a template must be instantiable: index findings already reported
        if (info.instantiationBoundingBoxLimit != 0) {
            const uint32_t align = properties_.cluster_template_bounds_byte_alignment;
            if (align && info.instantiationBoundingBoxLimit % align != 0)
                r.add(
                    "VUID-VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV-"
                    "instantiationBoundingBoxLimit-10505",
                    "instantiationBoundingBoxLimit is not aligned to "
                    "clusterTemplateBoundsByteAlignment " +
                        std::to_string(align),
                    info.instantiationBoundingBoxLimit);
            const auto b = memory.read_bytes(info.instantiationBoundingBoxLimit, 24,
                                             {"instantiationBoundingBoxLimit", op_index});
            std::memcpy(in.bounds_limit, b.data(), 24);
            in.has_bounds_limit = true;
        }
    } catch (const MemoryFault& f) {
        report_fault(f, r);
        return no_object(out);
    }
    in.type = ObjectType::kTriangleClusterTemplate;
    set_shared_encode_fields(view_of(info), input, d, s.index_bytes, s.geometry, s.omm, in);
    in.positions = d.has_positions ? d.positions : nullptr;
    detail::encode_object(in, s.encode, stores_, out);
    return true;
}

bool ClusterBuilder::instantiate_triangle_cluster(
    const MemoryImage& memory, const VkClusterAccelerationStructureInstantiateClusterInfoNV& info,
    const VkClusterAccelerationStructureTriangleClusterInputNV& input, int64_t op_index,
    std::vector<std::byte>& out, std::vector<Finding>& findings) {
    Reporter r{findings, op_index, "VkClusterAccelerationStructureInstantiateClusterInfoNV"};
    Scratch& s = *scratch_;
    check_instantiate_info(info, input, properties_, r);
    try {
        const TemplateRead tmpl =
            read_cluster_template(memory, info.clusterTemplateAddress, op_index, r);
        if (!tmpl.header) return no_object(out);
        const ObjectHeader& h = *tmpl.header;
        const uint32_t format = common::enum_bits(input.vertexFormat);
        if (format != h.vertex_format)
            r.add("VUID-VkClusterAccelerationStructureInstantiateClusterInfoNV-vertexBuffer-10508",
                  "vertexFormat " + std::to_string(int(format)) + " differs from the template's " +
                      std::to_string(h.vertex_format));
        if (!instance_positions({memory, info, input, tmpl.bytes, h, op_index}, s.positions, r))
            return no_object(out);
        if (h.header_flags & kHasBoundsLimit)
            check_bounds_limit(tmpl.bytes, h, s.positions, info.vertexBuffer.startAddress, r);
        const int32_t offset = geometry_index_offset(info);
        const GeometryIndexRange range =
            instance_triangles(tmpl.bytes, h, offset, s.index_bytes, s.geometry, s.inactive);
        check_geometry_index_range(range, offset, properties_, r);
        const detail::EncodeInput in =
            instance_encode_input(tmpl.bytes, h, info,
                                  {s.positions, s.index_bytes, s.inactive, s.geometry, s.omm});
        detail::encode_object(in, s.encode, stores_, out);
        return true;
    } catch (const MemoryFault& f) {
        report_fault(f, r);
        return no_object(out);
    }
}

bool ClusterBuilder::build_from_arrays(uint32_t cluster_id, std::span<const float> positions,
                                       std::span<const uint32_t> indices, uint32_t truncate_bits,
                                       uint32_t base_geometry_index_and_flags,
                                       std::span<const uint32_t> geometry_index_and_flags,
                                       std::vector<std::byte>& out,
                                       std::vector<Finding>& findings) {
    Reporter r{findings, -1, "build_from_arrays"};
    Scratch& s = *scratch_;
    const size_t n_vertices = positions.size() / 3, n_triangles = indices.size() / 3;
    if (n_vertices > kMaxVertices || n_triangles > kMaxTriangles || positions.size() % 3 ||
        indices.size() % 3 || truncate_bits > 32 ||
        (!geometry_index_and_flags.empty() && geometry_index_and_flags.size() != n_triangles)) {
        r.add(kRuleCountAboveInput, "arrays exceed 256 vertices/triangles or are malformed");
        return no_object(out);
    }
    for (size_t c = 0; c < positions.size(); ++c)
        s.positions[c] = truncate_position(positions[c], truncate_bits);
    uint32_t bad = 0;
    for (size_t t = 0; t < n_triangles; ++t) {
        s.inactive[t] = 0;
        for (int v = 0; v < 3; ++v) {
            s.index_bytes[3 * t + v] = uint8_t(indices[3 * t + v]);
            if (indices[3 * t + v] >= n_vertices) {
                s.inactive[t] = 1;
                ++bad;
            }
        }
    }
    if (bad)
        r.add(kRuleIndexOutOfRange,
              std::to_string(bad) +
                  " index value(s) >= vertex count; those triangles are inactive");
    detail::EncodeInput in;
    in.cluster_id = cluster_id;
    in.triangle_count = uint32_t(n_triangles);
    in.vertex_count = uint32_t(n_vertices);
    in.truncate_bits = truncate_bits;
    in.vertex_format = VK_FORMAT_R32G32B32_SFLOAT;
    in.positions = s.positions;
    s.index_bytes[3 * n_triangles] = 0;
    in.index_bytes = s.index_bytes;
    in.inactive = s.inactive;
    in.base_geometry_index_and_flags = base_geometry_index_and_flags;
    in.geometry_index_and_flags =
        geometry_index_and_flags.empty() ? nullptr : geometry_index_and_flags.data();
    detail::encode_object(in, s.encode, stores_, out);
    return true;
}

namespace {

// A ClusterBuilder op taking an info of type Info: the one-shot forms differ only in it.
template <class Info>
using BuilderOp = bool (ClusterBuilder::*)(
    const MemoryImage&, const Info&, const VkClusterAccelerationStructureTriangleClusterInputNV&,
    int64_t, std::vector<std::byte>&, std::vector<Finding>&);

template <class Info>
ClusterObject run_once(BuilderOp<Info> op, const MemoryImage& memory, const Info& info,
                       const VkClusterAccelerationStructureTriangleClusterInputNV& input,
                       const EngineProperties& properties, int64_t op_index) {
    ClusterObject o;
    ClusterBuilder b(properties);
    o.ok = (b.*op)(memory, info, input, op_index, o.bytes, o.findings);
    return o;
}

}  // namespace

ClusterObject build_triangle_cluster(
    const MemoryImage& memory, const VkClusterAccelerationStructureBuildTriangleClusterInfoNV& info,
    const VkClusterAccelerationStructureTriangleClusterInputNV& input,
    const EngineProperties& properties, int64_t op_index) {
    return run_once(&ClusterBuilder::build_triangle_cluster, memory, info, input, properties,
                    op_index);
}

ClusterObject build_triangle_cluster_template(
    const MemoryImage& memory,
    const VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV& info,
    const VkClusterAccelerationStructureTriangleClusterInputNV& input,
    const EngineProperties& properties, int64_t op_index) {
    return run_once(&ClusterBuilder::build_triangle_cluster_template, memory, info, input,
                    properties, op_index);
}

ClusterObject instantiate_triangle_cluster(
    const MemoryImage& memory, const VkClusterAccelerationStructureInstantiateClusterInfoNV& info,
    const VkClusterAccelerationStructureTriangleClusterInputNV& input,
    const EngineProperties& properties, int64_t op_index) {
    return run_once(&ClusterBuilder::instantiate_triangle_cluster, memory, info, input, properties,
                    op_index);
}

ClusterObject get_cluster_template_indices(
    const MemoryImage& memory, const VkClusterAccelerationStructureGetTemplateIndicesInfoNV& info,
    int64_t op_index) {
    ClusterObject o;
    Reporter r{o.findings, op_index, "VkClusterAccelerationStructureGetTemplateIndicesInfoNV"};
    try {
        const TemplateRead tmpl =
            read_cluster_template(memory, info.clusterTemplateAddress, op_index, r);
        if (!tmpl.header) return o;
        const std::span<const std::byte> bytes = tmpl.bytes;
        const ObjectHeader& h = *tmpl.header;
        o.bytes.assign(12 * size_t(h.triangle_count), std::byte{0});
        for (uint32_t i = 0; i < h.triangle_count; ++i) {
            const DecodedTriangle tri = decode_triangle(bytes, h, i);
            for (int v = 0; v < 3; ++v) {
                const uint32_t value = tri.local_indices[v];
                std::memcpy(o.bytes.data() + 12 * size_t(tri.original_index) + 4 * v, &value, 4);
            }
        }
        o.ok = true;
    } catch (const MemoryFault& f) {
        report_fault(f, r);
    }
    return o;
}

uint64_t max_cluster_object_size(const VkClusterAccelerationStructureTriangleClusterInputNV& input,
                                 const EngineProperties& properties, bool is_template) {
    const uint64_t n_triangles =
        std::min(input.maxClusterTriangleCount,
                 std::min(properties.max_triangles_per_cluster, kMaxTriangles));
    const uint64_t n_vertices =
        std::min(input.maxClusterVertexCount,
                 std::min(properties.max_vertices_per_cluster, kMaxVertices));
    const uint64_t bits = 32 - std::min<uint32_t>(input.minPositionTruncateBitCount, 32);
    uint64_t size = sizeof(ObjectHeader);
    if (!is_template) size += 8 * (n_triangles ? 2 * n_triangles - 1 : 0);
    size += ((n_vertices * 3 * bits + 7) / 8 + 3) & ~3ull;
    size += 3 * n_triangles + n_triangles + 3;                     // indices, order, padding
    size += 4 * n_triangles;                                       // per-triangle geometry data
    size += 8 + sizeof(OpacityMicromapSection) + 4 * n_triangles;  // OMM
    if (is_template) size += 24;
    return (size + 3) & ~3ull;
}

}  // namespace clastrace::engine
