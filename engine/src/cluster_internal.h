// SPDX-License-Identifier: Apache-2.0
// Internals shared by the cluster encoder, the decoder and traversal.
#pragma once

#include "clastrace/engine/cluster_build.h"
#include "clastrace/engine/cluster_format.h"

#include <cstddef>
#include <cstdint>
#include <cstring>
#include <vector>

namespace clastrace::engine::detail {

inline constexpr uint32_t kMaxVertices = 256;
inline constexpr uint32_t kMaxTriangles = 256;
inline constexpr uint32_t kMaxNodes = 2 * kMaxTriangles - 1;

// Everything an object is encoded from, already decoded, truncated and validated.
struct EncodeInput {
    ObjectType type = ObjectType::kTriangleCluster;
    uint32_t cluster_id = 0;
    uint32_t cluster_flags = 0;
    uint32_t triangle_count = 0;
    uint32_t vertex_count = 0;
    uint32_t truncate_bits = 0;  // 0..32
    uint32_t vertex_format = 0;
    const float* positions = nullptr;  // vertex_count * 3 truncated floats, nullptr = none
    // triangle_count * 3 indices' low bytes (what the object stores: an active triangle's
    // indices are below vertex_count, at most 256), and one more readable byte after them.
    const uint8_t* index_bytes = nullptr;
    const uint8_t* inactive = nullptr;  // triangle_count flags (index out of range), nullptr = none
    uint32_t base_geometry_index_and_flags = 0;
    const uint32_t* geometry_index_and_flags =
        nullptr;  // triangle_count final values, nullptr = all base
    bool has_omm = false;
    uint64_t omm_array = 0;
    uint32_t omm_index_type = 0;
    const int32_t* omm_indices = nullptr;  // triangle_count
    bool has_bounds_limit = false;
    float bounds_limit[6] = {};
};

// Scratch for the BVH build, sized once for the largest cluster.
struct BvhScratch {
    // Boxes and centroids of the active triangles by their position in the active list (the
    // caller fills them, and the centroids' bounds): xyz + padding, 16-byte aligned for 4-wide
    // min/max. A centroid is the half-sum of its box's corners (no overflow near FLT_MAX), a
    // NaN lane (infinities that cancel) taken as 0.
    alignas(16) float tri_min[kMaxTriangles][4];
    alignas(16) float tri_max[kMaxTriangles][4];
    alignas(16) float centroid[kMaxTriangles][4];
    alignas(16) float centroid_min[4];
    alignas(16) float centroid_max[4];
    struct Node {
        alignas(16) float lo[4];
        alignas(16) float hi[4];  // lane 3 unused
        uint16_t link;  // the stored BvhNode::link: a leaf's triangles or an interior's left child
    } nodes[kMaxNodes];
    uint32_t node_count = 0;
};

// Builds a BVH over the n active triangles (their indices in `active_list`, increasing, or
// nullptr when they are 0, 1, ..., n - 1; their boxes, centroids and centroid bounds in the
// scratch); fills order[0..n) with the BVH order (triangle indices) and scratch.nodes.
// Returns whether that order is 0, 1, ..., n - 1.
bool build_bvh(const uint8_t* active_list, uint32_t n, BvhScratch& s, uint8_t* order);

// The largest object: a template's or CLAS's sections at 256 triangles and vertices, every
// optional one present, with their alignment padding.
inline constexpr uint32_t kMaxObjectBytes =
    sizeof(ObjectHeader) + 8 * kMaxNodes + 12 * kMaxVertices + 3 + 4 * kMaxTriangles + 3 +
    4 * kMaxTriangles + 7 + sizeof(OpacityMicromapSection) + 4 * kMaxTriangles + 24 + 3;

// Where the widened vertices start, counted from the BVH scratch modulo 4 KiB: its per-triangle
// arrays are 4 KiB each, so lines 4 KiB apart fall into the same L1 set (64 sets of 64 bytes)
// and the first triangles' boxes and centroids already share the low sets; the vertices (a
// cluster's first kilobyte or so in use) start at set 56 instead of set 0 beside them. The
// count of conflict misses depends on this (and on where the stack lies): callgrind's D1
// misses per WusonOBJ cluster were 55.6 at 0, 46.9-63.5 at 2560, 49.6-51.3 at 3584.
inline constexpr size_t kVertexSetOffset = 3584;

// Scratch for encode_object: the BVH's, the widened vertices, and the object itself where it is
// streamed out.
struct EncodeScratch {
    BvhScratch bvh;
    std::byte vertex_apart[(kVertexSetOffset + 4096 - sizeof(BvhScratch) % 4096) % 4096];
    alignas(16) float vertex[kMaxVertices][4];  // the vertices as x, y, z, 0 lanes
    alignas(64) std::byte object[kMaxObjectBytes];
};
static_assert(offsetof(EncodeScratch, vertex) % 4096 == kVertexSetOffset);

// Encodes the object into `out` (sized to it, zero padded) as `stores` says. Returns its size.
uint32_t encode_object(const EncodeInput& in, EncodeScratch& scratch, ObjectStores stores,
                       std::vector<std::byte>& out);

// Quantized box decoding: identical code for build and traversal (no FMA, see CMake).
struct QuantFrame {
    float lo[3];
    float step[3];
    float hi[3];
};
inline QuantFrame make_frame(const float bmin[3], const float bmax[3]) {
    QuantFrame f;
    for (int a = 0; a < 3; ++a) {
        f.lo[a] = bmin[a];
        f.hi[a] = bmax[a];
        const float ext = bmax[a] - bmin[a];
        f.step[a] = ext / 255.0f;
    }
    return f;
}
inline float dequant_lo(const QuantFrame& f, int a, uint32_t q) {
    if (q == 0) return f.lo[a];
    const float off = float(q) * f.step[a];
    const float r = f.lo[a] + off;
    return r;
}
inline float dequant_hi(const QuantFrame& f, int a, uint32_t q) {
    if (q == 255) return f.hi[a];
    const float off = float(q) * f.step[a];
    const float r = f.lo[a] + off;
    return r;
}

inline uint32_t read_u32(const std::byte* p) {
    uint32_t v;
    std::memcpy(&v, p, 4);
    return v;
}

// Reads stored coordinate `c` (0-based over vertex*3 + axis) from a packed section.
inline float unpack_coordinate(const std::byte* section, uint32_t section_size, uint32_t bits,
                               uint32_t truncate, uint32_t c) {
    if (bits == 32) {
        float f;
        std::memcpy(&f, section + 4 * size_t(c), 4);
        return f;
    }
    if (bits == 0) return 0.0f;
    const uint64_t bitpos = uint64_t(c) * bits;
    const uint32_t byte = uint32_t(bitpos >> 3);
    uint64_t word = 0;
    const uint32_t avail = section_size - byte;
    std::memcpy(&word, section + byte, avail < 8 ? avail : 8);
    const uint32_t value = uint32_t(word >> (bitpos & 7)) & ((1u << bits) - 1u);
    const uint32_t pattern = value << truncate;
    float f;
    std::memcpy(&f, &pattern, 4);
    return f;
}

// The three coordinates of vertex `v` from a packed section (bits 1..31).
inline void unpack_vertex(const std::byte* section, uint32_t avail, uint32_t bits,
                          uint32_t truncate, uint32_t v, float xyz[3]) {
    const uint64_t mask = (uint64_t(1) << bits) - 1u;
    uint64_t bitpos = uint64_t(v) * 3u * bits;
    for (int k = 0; k < 3; ++k, bitpos += bits) {
        const uint32_t byte = uint32_t(bitpos >> 3);
        uint64_t word = 0;
        const uint32_t left = avail - byte;
        std::memcpy(&word, section + byte, left < 8 ? left : 8);
        const uint32_t pattern = uint32_t((word >> (bitpos & 7)) & mask) << truncate;
        std::memcpy(&xyz[k], &pattern, 4);
    }
}

inline uint32_t packed_section_size(uint32_t vertex_count, uint32_t bits) {
    return uint32_t((uint64_t(vertex_count) * 3 * bits + 7) / 8);
}

inline uint32_t align4(uint32_t v) { return (v + 3u) & ~3u; }

}  // namespace clastrace::engine::detail
