// SPDX-License-Identifier: Apache-2.0
// Input reading for vkCmdBuildAccelerationStructureNV. Every range is checked before a
// byte is read (MemoryImage faults name the field), and every element count is bounded
// by bytes that exist, so hostile counts and strides cannot allocate without limit.
#include "nv_gather.h"
#include "clastrace/common/hex.h"

#include "clastrace/engine/blas.h"
#include "clastrace/engine/vertex_format.h"
#include "nv_internal.h"

#include <emmintrin.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <unordered_map>

namespace clastrace::engine::nv {
namespace {

using common::hex;

// Bytes covering `count` elements of `size` at `stride` (count > 0), or nullopt on overflow.
std::optional<uint64_t> strided_span(uint64_t count, uint64_t stride, uint64_t size) {
    const unsigned __int128 n = static_cast<unsigned __int128>(count - 1) * stride + size;
    if (n > ~0ull) return std::nullopt;
    return uint64_t(n);
}

std::span<const std::byte> read_span(Context& c, uint64_t address, uint64_t count, uint64_t stride,
                                     uint64_t size, const std::string& field) {
    std::optional<uint64_t> bytes = strided_span(count, stride, size);
    if (!bytes)
        MemoryImage::fault(address, ~0ull, FieldRef{field.c_str(), -1},
                           "element count times stride overflows 64 bits");
    auto span = c.memory.read_bytes(address, *bytes, FieldRef{field.c_str(), -1});
    c.access(address, *bytes, kAccessInputBuffer, false, field);
    return span;
}

float load_float(const std::byte* p) {
    float f;
    std::memcpy(&f, p, 4);
    return f;
}

}  // namespace

uint32_t nv_vertex_size(VkFormat format) {
    switch (format) {
    case VK_FORMAT_R32G32B32_SFLOAT: return 12;
    case VK_FORMAT_R32G32_SFLOAT: return 8;
    case VK_FORMAT_R16G16B16_SFLOAT:
    case VK_FORMAT_R16G16B16_SNORM: return 6;
    case VK_FORMAT_R16G16_SFLOAT:
    case VK_FORMAT_R16G16_SNORM: return 4;
    default: return 0;
    }
}

uint32_t nv_component_size(VkFormat format) {
    return format == VK_FORMAT_R32G32B32_SFLOAT || format == VK_FORMAT_R32G32_SFLOAT ? 4 : 2;
}

bool decode_nv_vertex(VkFormat format, const std::byte* src, float xyz[3]) {
    if (format == VK_FORMAT_R16G16B16_SNORM) {
        for (int a = 0; a < 3; ++a) {
            int16_t v;
            std::memcpy(&v, src + 2 * a, 2);
            xyz[a] = std::max(float(v) / 32767.0f, -1.0f);
        }
        return true;
    }
    if (nv_vertex_size(format) == 0) return false;
    decode_vertex(format, src, xyz);
    return true;
}

namespace {

uint32_t nv_index_size(VkIndexType type) {
    return type == VK_INDEX_TYPE_UINT16 ? 2 : type == VK_INDEX_TYPE_UINT32 ? 4 : 0;
}

// The box's lanes 0-2 (lane 3 zero).
void load_box(const Box& b, __m128* lo, __m128* hi) {
    *lo = _mm_setr_ps(b.lo[0], b.lo[1], b.lo[2], 0.0f);
    *hi = _mm_setr_ps(b.hi[0], b.hi[1], b.hi[2], 0.0f);
}

void store_box(__m128 lo, __m128 hi, Box* box) {
    _mm_storeu_ps(box->lo, lo);  // (hi[0] written next)
    _mm_storel_pi(reinterpret_cast<__m64*>(box->hi), hi);
    _mm_store_ss(box->hi + 2, _mm_movehl_ps(hi, hi));
}

// The bounds of the boxes' centroids (BottomInput::centroids), kept in registers while the
// boxes are read. The centroid is nv_tree.cpp's: the halves added, so that coordinates near
// FLT_MAX do not overflow; minps/maxps keep the bounds when a centroid is NaN.
struct CentroidBounds {
    __m128 lo = _mm_set1_ps(std::numeric_limits<float>::infinity());
    __m128 hi = _mm_set1_ps(-std::numeric_limits<float>::infinity());

    void grow(__m128 box_lo, __m128 box_hi) {
        const __m128 half = _mm_set1_ps(0.5f);
        const __m128 c = _mm_add_ps(_mm_mul_ps(box_lo, half), _mm_mul_ps(box_hi, half));
        lo = _mm_min_ps(c, lo);
        hi = _mm_max_ps(c, hi);
    }
    // Into `bounds`, grown by what it held.
    void merge_into(Box& bounds) const {
        __m128 old_lo, old_hi;
        load_box(bounds, &old_lo, &old_hi);
        store_box(_mm_min_ps(lo, old_lo), _mm_max_ps(hi, old_hi), &bounds);
    }
};

// Geometry g's boxes; NaN or inverted boxes stay inactive.
void gather_aabbs(Context& c, const NvAabbs& a, uint32_t g, const std::string& at, BottomInput& in,
                  NvGeometryRecord& rec) {
    rec.input_primitives = a.count;
    rec.vertex_count = a.stride;
    if (a.address != 0 && a.available == 0)
        c.finding(kVuidAabbOffset, at + ".geometry.aabbs.offset " + std::to_string(a.offset) +
                                       " is not below the size of aabbData");
    if (a.offset % 8)
        c.finding(kVuidAabbOffsetAlign, at + ".geometry.aabbs.offset " + std::to_string(a.offset) +
                                            " is not a multiple of 8");
    if (a.stride % 8)
        c.finding(kVuidAabbStride, at + ".geometry.aabbs.stride " + std::to_string(a.stride) +
                                       " is not a multiple of 8");
    std::span<const std::byte> bytes;
    if (a.count)
        bytes = read_span(c, a.address, a.count, a.stride, 24, at + ".geometry.aabbs.aabbData");
    for (uint32_t i = 0; i < a.count; ++i) {
        NvPrimitiveRecord p{};
        for (int k = 0; k < 6; ++k)
            p.v[k] = load_float(bytes.data() + uint64_t(i) * a.stride + 4 * k);
        p.geometry_index = g;
        p.primitive_index = i;
        bool active = !std::isnan(p.v[0]);
        if (active) {
            for (int k = 1; k < 6; ++k)
                if (std::isnan(p.v[k])) {
                    c.finding(c.dialect.nan_component,
                              at + " AABB " + std::to_string(i) +
                                  ": NaN in a component other than minX (undefined behaviour; the "
                                  "engine treats it as inactive)");
                    active = false;
                    break;
                }
        }
        static const char* k_min_max[3] = {"VUID-VkAabbPositionsKHR-minX-03546",
                                           "VUID-VkAabbPositionsKHR-minY-03547",
                                           "VUID-VkAabbPositionsKHR-minZ-03548"};
        for (int k = 0; active && k < 3; ++k)
            if (p.v[k] > p.v[3 + k]) {
                c.finding(k_min_max[k],
                          at + " AABB " + std::to_string(i) + ": minimum above maximum on axis " +
                              std::to_string(k) + " (the engine treats it as inactive)",
                          a.address + uint64_t(i) * a.stride);
                active = false;
            }
        in.primitives.push_back(p);
        in.active.push_back(active);
        rec.active_primitives += active;
        if (!active) continue;
        in.boxes.push_back(Box{{p.v[0], p.v[1], p.v[2]}, {p.v[3], p.v[4], p.v[5]}});
        CentroidBounds centroid;
        centroid.grow(_mm_setr_ps(p.v[0], p.v[1], p.v[2], 0.0f),
                      _mm_setr_ps(p.v[3], p.v[4], p.v[5], 0.0f));
        centroid.merge_into(in.centroids);
        in.source.push_back(uint32_t(in.primitives.size() - 1));
    }
}

// The triangle geometry's formats, offsets and counts. Returns false when its triangles
// cannot be read.
bool check_triangles(Context& c, const NvTriangles& t, const std::string& at) {
    const uint32_t vsize = c.dialect.vertex_size(t.vertex_format);
    const bool none = t.index_type == VK_INDEX_TYPE_NONE_NV;
    const uint32_t isize = nv_index_size(t.index_type);
    bool usable = true;
    if (vsize == 0) {
        c.finding(c.dialect.vertex_format, at + ".geometry.triangles.vertexFormat " +
                                               std::to_string(uint32_t(t.vertex_format)) +
                                               " is not one " + c.dialect.formats_by + " allows");
        usable = false;
    } else if (t.vertex_offset % c.dialect.component_size(t.vertex_format)) {
        c.finding(kVuidVertexOffsetAlign, at + ".geometry.triangles.vertexOffset " +
                                              std::to_string(t.vertex_offset) +
                                              " is not a multiple of the component size");
    }
    if (t.vertex_address != 0 && t.vertex_available == 0)
        c.finding(kVuidVertexOffset, at + ".geometry.triangles.vertexOffset " +
                                         std::to_string(t.vertex_offset) +
                                         " is not below the size of vertexData");
    if (!none && isize == 0) {
        c.finding(kVuidIndexType, at + ".geometry.triangles.indexType " +
                                      std::to_string(uint32_t(t.index_type)) +
                                      " is not UINT16, UINT32 or NONE_NV");
        usable = false;
    }
    if (none && t.index_address != 0)
        c.finding(kVuidIndexNoneData, at + ".geometry.triangles.indexType is VK_INDEX_TYPE_NONE_NV "
                                           "but indexData is not VK_NULL_HANDLE");
    if (none && t.index_count != 0)
        c.finding(kVuidIndexNoneCount,
                  at + ".geometry.triangles.indexType is VK_INDEX_TYPE_NONE_NV but indexCount is " +
                      std::to_string(t.index_count));
    if (!none && isize) {
        if (t.index_address != 0 && t.index_available == 0)
            c.finding(kVuidIndexOffset, at + ".geometry.triangles.indexOffset " +
                                            std::to_string(t.index_offset) +
                                            " is not below the size of indexData");
        if (t.index_offset % isize)
            c.finding(kVuidIndexOffsetAlign, at + ".geometry.triangles.indexOffset " +
                                                 std::to_string(t.index_offset) +
                                                 " is not a multiple of the index size");
        if (t.index_count % 3)
            c.finding(kRuleNvPartialTriangle,
                      at + ".geometry.triangles.indexCount " + std::to_string(t.index_count) +
                          " is not a multiple of 3: the last indices form no triangle");
    }
    if (t.transform_address != 0) {
        if (t.transform_available == 0)
            c.finding(kVuidTransformOffset, at + ".geometry.triangles.transformOffset " +
                                                std::to_string(t.transform_offset) +
                                                " is not below the size of transformData");
        if (t.transform_offset % 16)
            c.finding(kVuidTransformOffsetAlign, at + ".geometry.triangles.transformOffset " +
                                                     std::to_string(t.transform_offset) +
                                                     " is not a multiple of 16");
    }
    return usable;
}

// x, y, z of the float3 vertex at p, lane 3 zero (no byte past the vertex is read). The
// bytes go through memcpy: a vertex stride need not align p for a double (UBSan), and the
// compiler still makes one 8-byte and one 4-byte load of them.
__m128 load_float3(const std::byte* p) {
    double xy_bits;
    float z;
    std::memcpy(&xy_bits, p, sizeof xy_bits);
    std::memcpy(&z, p + 8, sizeof z);
    return _mm_movelh_ps(_mm_castpd_ps(_mm_set_sd(xy_bits)), _mm_set_ss(z));
}

// Triangle i's three vertex indices; IndexSize 0 is VK_INDEX_TYPE_NONE_NV.
template <uint32_t IndexSize>
void triangle_indices(const std::byte* indices, uint32_t i, uint32_t index[3]) {
    if constexpr (IndexSize == 0) {
        index[0] = 3 * i;
        index[1] = 3 * i + 1;
        index[2] = 3 * i + 2;
    } else if constexpr (IndexSize == 2) {
        uint16_t narrow[3];
        std::memcpy(narrow, indices + 6 * uint64_t(i), 6);
        for (int k = 0; k < 3; ++k) index[k] = narrow[k];
    } else {
        std::memcpy(index, indices + 12 * uint64_t(i), 12);
    }
}

// Triangle i of float3 vertices with no transform, the common case, without a branch per
// coordinate: true when its indices are below vertexCount and no coordinate is NaN (p.v and
// *box filled, the box as triangle_box gives it); false leaves it to the full reading.
template <uint32_t IndexSize>
bool fast_triangle(const NvTriangles& t, uint32_t i, const std::byte* vertices,
                   const std::byte* indices, NvPrimitiveRecord& p, __m128* lo, __m128* hi) {
    uint32_t index[3];
    triangle_indices<IndexSize>(indices, i, index);
    if ((index[0] >= t.vertex_count) | (index[1] >= t.vertex_count) | (index[2] >= t.vertex_count))
        return false;
    const uint64_t stride = t.vertex_stride;
    const __m128 v0 = load_float3(vertices + index[0] * stride),
                 v1 = load_float3(vertices + index[1] * stride),
                 v2 = load_float3(vertices + index[2] * stride);
    const __m128 nan = _mm_or_ps(_mm_cmpunord_ps(v0, v0),
                                 _mm_or_ps(_mm_cmpunord_ps(v1, v1), _mm_cmpunord_ps(v2, v2)));
    if (_mm_movemask_ps(nan) != 0) return false;
    // Overlapping stores, each vertex's zero lane overwritten by the next (the last one's by
    // the geometry index, written after).
    _mm_storeu_ps(p.v, v0);
    _mm_storeu_ps(p.v + 3, v1);
    _mm_storeu_ps(p.v + 6, v2);
    // triangle_box's operand order, which decides between -0 and +0.
    *lo = _mm_min_ps(v2, _mm_min_ps(v1, v0));
    *hi = _mm_max_ps(v2, _mm_max_ps(v1, v0));
    return true;
}

// One triangle geometry's readable inputs, for append_triangles.
struct TriangleSource {
    const NvTriangles& t;
    uint32_t geometry;
    bool plain;  // float3 vertices and no transform: fast_triangle may read them
    const std::byte* vertices;
    const std::byte* indices;
};

// Appends the geometry's `count` triangles to `in` (records, flags, and the boxes and record
// indices of the active ones): the common case by fast_triangle, any other by
// read_triangle(i, record), false for an inactive one. Returns how many are active.
template <uint32_t IndexSize, class ReadTriangle>
uint32_t append_triangles(const TriangleSource& s, uint32_t count, BottomInput& in,
                          ReadTriangle& read_triangle) {
    const size_t base = in.primitives.size(), boxes_base = in.boxes.size();
    in.primitives.resize(base + count);
    in.active.resize(base + count);
    in.boxes.resize(boxes_base + count);
    in.source.resize(boxes_base + count);
    NvPrimitiveRecord* out = in.primitives.data() + base;
    uint8_t* out_active = in.active.data() + base;
    Box* out_box = in.boxes.data() + boxes_base;
    uint32_t* out_source = in.source.data() + boxes_base;
    uint32_t active_count = 0;
    CentroidBounds centroids;
    for (uint32_t i = 0; i < count; ++i) {
        NvPrimitiveRecord& p = out[i];
        __m128 lo, hi;
        bool active =
            s.plain && fast_triangle<IndexSize>(s.t, i, s.vertices, s.indices, p, &lo, &hi);
        if (!active) {
            std::fill(std::begin(p.v), std::end(p.v), 0.0f);  // as a fresh record
            active = read_triangle(i, p);
            if (active) load_box(triangle_box(p.v), &lo, &hi);
        }
        p.geometry_index = s.geometry;
        p.primitive_index = i;
        p.reserved = 0;
        out_active[i] = active;
        if (active) {
            store_box(lo, hi, out_box + active_count);
            centroids.grow(lo, hi);
        }
        out_source[active_count] = uint32_t(base + i);
        active_count += active;
    }
    centroids.merge_into(in.centroids);
    in.boxes.resize(boxes_base + active_count);
    in.source.resize(boxes_base + active_count);
    return active_count;
}

// Geometry g's triangles, indexed, decoded and transformed; unreadable ones stay inactive.
void gather_triangles(Context& c, const NvTriangles& t, uint32_t g, const std::string& at,
                      BottomInput& in, NvGeometryRecord& rec) {
    rec.vertex_format = uint32_t(t.vertex_format);
    rec.index_type = uint32_t(t.index_type);
    rec.vertex_count = t.vertex_count;
    rec.has_transform = t.transform_address != 0;
    const uint32_t vsize = c.dialect.vertex_size(t.vertex_format);
    const bool none = t.index_type == VK_INDEX_TYPE_NONE_NV;
    const uint32_t isize = nv_index_size(t.index_type);
    const bool usable = check_triangles(c, t, at);
    const uint32_t count = none ? t.vertex_count / 3 : t.index_count / 3;
    rec.input_primitives = count;
    if (!usable || count == 0) {
        // Nothing readable: every triangle of this geometry stays inactive.
        for (uint32_t i = 0; i < count; ++i) {
            NvPrimitiveRecord p{};
            p.geometry_index = g;
            p.primitive_index = i;
            in.primitives.push_back(p);
            in.active.push_back(0);
        }
        return;
    }
    std::span<const std::byte> vertices;
    if (t.vertex_count)
        vertices = read_span(c, t.vertex_address, t.vertex_count, t.vertex_stride, vsize,
                             at + ".geometry.triangles.vertexData");
    std::span<const std::byte> indices;
    if (!none)
        indices = read_span(c, t.index_address, uint64_t(count) * 3, isize, isize,
                            at + ".geometry.triangles.indexData");
    float m[12] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0};
    if (t.transform_address != 0) {
        auto bytes =
            read_span(c, t.transform_address, 1, 48, 48, at + ".geometry.triangles.transformData");
        std::memcpy(m, bytes.data(), 48);
    }
    const bool float3 =
        t.vertex_format == VK_FORMAT_R32G32B32_SFLOAT;  // the common format: a plain copy
    // Triangle i as the spec reads it, with a finding for each rule it breaks; false for an
    // inactive triangle.
    auto read_triangle = [&](uint32_t i, NvPrimitiveRecord& p) {
        bool active = true;
        for (int k = 0; k < 3; ++k) {
            uint32_t index = 3 * i + k;
            if (!none) {
                if (isize == 2) {
                    uint16_t v;
                    std::memcpy(&v, indices.data() + 2 * (3 * uint64_t(i) + k), 2);
                    index = v;
                } else {
                    std::memcpy(&index, indices.data() + 4 * (3 * uint64_t(i) + k), 4);
                }
            }
            if (index >= t.vertex_count) {
                c.finding(c.dialect.index_out_of_range,
                          at + " triangle " + std::to_string(i) + ": index " +
                              std::to_string(index) + " is not below " + c.dialect.vertex_count +
                              " " + std::to_string(t.vertex_count) +
                              " (the engine treats the triangle as inactive)");
                return false;
            }
            const std::byte* vertex = vertices.data() + uint64_t(index) * t.vertex_stride;
            if (float3)
                std::memcpy(p.v + 3 * k, vertex, 12);
            else
                c.dialect.decode_vertex(t.vertex_format, vertex, p.v + 3 * k);
        }
        if (std::isnan(p.v[0]) || std::isnan(p.v[3]) || std::isnan(p.v[6]))
            return false;  // the spec's inactive triangle
        for (int k : {1, 2, 4, 5, 7, 8})
            if (std::isnan(p.v[k])) {
                c.finding(c.dialect.nan_component, at + " triangle " + std::to_string(i) +
                                                       ": NaN in a Y or Z coordinate with X "
                                                       "not NaN (undefined behaviour; the "
                                                       "engine treats it as inactive)");
                return false;
            }
        if (t.transform_address == 0) return active;
        for (int k = 0; k < 3; ++k) {
            const float x = p.v[3 * k], y = p.v[3 * k + 1], z = p.v[3 * k + 2];
            for (int r = 0; r < 3; ++r)
                p.v[3 * k + r] = m[4 * r] * x + m[4 * r + 1] * y + m[4 * r + 2] * z + m[4 * r + 3];
        }
        for (int k = 0; k < 9; ++k)
            if (std::isnan(p.v[k])) {
                c.finding(c.dialect.nan_component, at + " triangle " + std::to_string(i) +
                                                       ": the transform gives a NaN coordinate "
                                                       "(the engine treats it as inactive)");
                return false;
            }
        return active;
    };
    // The common case first: float3 vertices, no transform, indices in range and no NaN. Any
    // other triangle is read again by read_triangle, which reports what it breaks.
    const bool plain = float3 && t.transform_address == 0;
    const TriangleSource source{t, g, plain, vertices.data(), indices.data()};
    if (isize == 2)
        rec.active_primitives += append_triangles<2>(source, count, in, read_triangle);
    else if (isize == 4)
        rec.active_primitives += append_triangles<4>(source, count, in, read_triangle);
    else
        rec.active_primitives += append_triangles<0>(source, count, in, read_triangle);
}

}  // namespace

namespace {

size_t capacity_bytes(const BottomInput& in) {
    return in.geometries.capacity() * sizeof(NvGeometryRecord) +
           in.primitives.capacity() * sizeof(NvPrimitiveRecord) + in.active.capacity() +
           in.boxes.capacity() * sizeof(Box) + in.source.capacity() * sizeof(uint32_t);
}

// The thread's kept input arrays; their bytes count as kept until taken or the thread ends.
struct KeptInput {
    BottomInput in;
    size_t bytes = 0;
    ~KeptInput() { release_kept_bytes(bytes); }
};
thread_local KeptInput t_kept_input;

// An empty input on the thread's kept arrays (none kept: fresh ones).
BottomInput take_bottom_input() {
    release_kept_bytes(t_kept_input.bytes);
    t_kept_input.bytes = 0;
    BottomInput in;
    in.geometries = std::move(t_kept_input.in.geometries);
    in.primitives = std::move(t_kept_input.in.primitives);
    in.active = std::move(t_kept_input.in.active);
    in.boxes = std::move(t_kept_input.in.boxes);
    in.source = std::move(t_kept_input.in.source);
    in.geometries.clear();
    in.primitives.clear();
    in.active.clear();
    in.boxes.clear();
    in.source.clear();
    return in;
}

}  // namespace

void recycle_bottom_input(BottomInput&& in) {
    const size_t bytes = capacity_bytes(in);
    if (bytes <= capacity_bytes(t_kept_input.in) || !claim_kept_bytes(bytes)) return;
    release_kept_bytes(t_kept_input.bytes);
    t_kept_input.in = std::move(in);
    t_kept_input.bytes = bytes;
}

BottomInput gather_bottom(Context& c) {
    BottomInput in = take_bottom_input();
    const auto& geometries = c.command.info.geometries;
    in.aabbs = !geometries.empty() && geometries[0].type == VK_GEOMETRY_TYPE_AABBS_NV;
    for (uint32_t g = 0; g < geometries.size(); ++g) {
        const NvGeometry& geo = geometries[g];
        const std::string at = c.dialect.geometries + "[" + std::to_string(g) + "]";
        NvGeometryRecord rec{};
        rec.geometry_flags = geo.flags;
        if (geo.type == VK_GEOMETRY_TYPE_AABBS_NV)
            gather_aabbs(c, geo.aabbs, g, at, in, rec);
        else
            gather_triangles(c, geo.triangles, g, at, in, rec);
        in.geometries.push_back(rec);
    }
    return in;
}

namespace {

// The 64-byte instance records, packed in input order, and the address each was read at.
// Instances given through an array of addresses are read one by one.
std::vector<std::byte> read_instances(Context& c, uint32_t count, std::vector<uint64_t>& at) {
    const std::string& field = c.dialect.instances;
    at.resize(count);
    if (!c.dialect.instance_pointers) {
        auto bytes = read_span(c, c.command.instance_address, count, 64, 64, field);
        for (uint32_t i = 0; i < count; ++i) at[i] = c.command.instance_address + uint64_t(i) * 64;
        return std::vector<std::byte>(bytes.begin(), bytes.end());
    }
    auto pointers = read_span(c, c.command.instance_address, count, 8, 8, field);
    std::vector<std::byte> packed(uint64_t(count) * 64);
    for (uint32_t i = 0; i < count; ++i) {
        std::memcpy(&at[i], pointers.data() + uint64_t(i) * 8, 8);
        const std::string element = field + "[" + std::to_string(i) + "]";
        if (at[i] % 16 && c.dialect.reference_alignment)
            c.finding(c.dialect.reference_alignment,
                      element + " " + hex(at[i]) + " is not aligned to 16 bytes", at[i]);
        auto bytes = read_span(c, at[i], 1, 64, 64, element + "->");
        std::memcpy(packed.data() + uint64_t(i) * 64, bytes.data(), 64);
    }
    return packed;
}

// The header of the bottom level an instance names: an NV or KHR object's own, or one made
// from a cluster BLAS's (blas.h), whose kind, size and bounds are all an instance needs.
// Throws MemoryFault when the address is outside memory.
std::optional<NvObjectHeader> instance_blas_header(const MemoryImage& memory, uint64_t address,
                                                   const std::string& field, std::string* error) {
    uint32_t magic = 0;
    std::memcpy(&magic, memory.read_bytes(address, 4, FieldRef{field.c_str(), -1}).data(), 4);
    if (magic != kObjectMagic)
        return read_nv_header(memory.read_bytes(address, sizeof(NvObjectHeader),
                                                FieldRef{field.c_str(), -1}),
                              error);
    const ObjectDirectory bytes_only;  // judged by the bytes: the replay's objects all check
    const ObjectLookup found = bytes_only.lookup(memory, address, ObjectType::kClustersBottomLevel,
                                                 false, FieldRef{field.c_str(), -1});
    if (!found.found()) {
        *error = found.error;
        return std::nullopt;
    }
    const BottomLevelCheck check = read_bottom_level_header(found.bytes);
    if (!check.header) {
        *error = "a cluster BLAS that does not check out: " + check.error;
        return std::nullopt;
    }
    NvObjectHeader h{};
    h.magic = kNvObjectMagic;
    h.kind = uint8_t(NvObjectKind::kBottomLevel);
    h.object_size = check.header->object_size;
    std::memcpy(h.bounds_min, check.header->bounds_min, sizeof h.bounds_min);
    std::memcpy(h.bounds_max, check.header->bounds_max, sizeof h.bounds_max);
    return h;
}

}  // namespace

TopInput gather_top(Context& c) {
    TopInput in;
    const uint32_t count = c.command.info.instance_count;
    if (count == 0) return in;
    if (c.command.instance_address == 0)
        MemoryImage::fault(0, uint64_t(count) * 64, FieldRef{c.dialect.instances.c_str(), -1},
                           "a top-level build with instanceCount > 0 needs instanceData");
    std::vector<uint64_t> record_address;
    const std::vector<std::byte> bytes = read_instances(c, count, record_address);
    std::unordered_map<uint64_t, std::optional<NvObjectHeader>>
        blas;  // address -> header (nullopt: none)
    in.instances.resize(count);
    for (uint32_t i = 0; i < count; ++i) {
        const std::byte* src = bytes.data() + uint64_t(i) * 64;
        NvInstanceRecord& r = in.instances[i];
        r = NvInstanceRecord{};
        std::memcpy(r.transform, src, 48);
        std::memcpy(&r.custom_index_and_mask, src + 48, 4);
        std::memcpy(&r.sbt_offset_and_flags, src + 52, 4);
        std::memcpy(&r.reference, src + 56, 8);
        Box empty = Box::empty();
        std::memcpy(r.world_min, empty.lo, 12);
        std::memcpy(r.world_max, empty.hi, 12);
        r.active = r.reference != 0;
        if (!r.active) continue;
        const std::string field =
            c.dialect.instances + "[" + std::to_string(i) + "].accelerationStructureReference";
        std::optional<uint64_t> address = c.options.resolve_reference
                                              ? c.options.resolve_reference(r.reference)
                                              : std::optional<uint64_t>(r.reference);
        if (!address) {
            c.finding(c.dialect.reference,
                      field + " " + hex(r.reference) + " is no " + c.dialect.reference_source +
                          " for a bottom-level object (the instance is left out)",
                      record_address[i] + 56);
            continue;
        }
        auto [it, fresh] = blas.try_emplace(*address);
        if (fresh) {
            std::string error;
            try {
                it->second = instance_blas_header(c.memory, *address, field, &error);
            } catch (const MemoryFault& f) {
                error = f.message;
            }
            if (it->second && it->second->kind != uint8_t(NvObjectKind::kBottomLevel)) {
                c.finding(c.dialect.reference,
                          field + " " + hex(r.reference) +
                              " names a top-level object (the instance is left out)",
                          *address);
                it->second.reset();
                error.clear();
            }
            if (!error.empty())
                c.finding(c.dialect.blas_not_built,
                          field + " " + hex(r.reference) + " at " + hex(*address) +
                              " holds no built bottom-level object: " + error +
                              " (the instance is left out)",
                          *address);
            if (it->second)
                c.access(*address, it->second->object_size, kAccessObjectRead, false, field);
        }
        if (!it->second) continue;
        r.blas_address = *address;
        for (float v : r.transform)
            if (std::isnan(v)) {
                c.finding(c.dialect.nan_component,
                          c.dialect.instances + "[" + std::to_string(i) +
                              "].transform holds NaN (the instance is left out of the tree)");
                break;
            }
        const Box local{{it->second->bounds_min[0], it->second->bounds_min[1],
                         it->second->bounds_min[2]},
                        {it->second->bounds_max[0], it->second->bounds_max[1],
                         it->second->bounds_max[2]}};
        if (!local.valid()) continue;  // a BLAS with nothing active: never hit
        const Box world = transform_box(local, r.transform);
        std::memcpy(r.world_min, world.lo, 12);
        std::memcpy(r.world_max, world.hi, 12);
    }
    return in;
}

}  // namespace clastrace::engine::nv
