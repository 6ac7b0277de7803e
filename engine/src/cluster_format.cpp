// SPDX-License-Identifier: Apache-2.0
#include "clastrace/engine/cluster_format.h"

#include "cluster_internal.h"

namespace clastrace::engine {

namespace {

bool section_fits(uint32_t offset, uint64_t bytes, uint32_t object_size) {
    return offset >= sizeof(ObjectHeader) && uint64_t(offset) + bytes <= object_size;
}

}  // namespace

HeaderCheck read_object_header(std::span<const std::byte> bytes) {
    HeaderCheck r;
    if (bytes.size() < sizeof(ObjectHeader)) {
        r.error = "fewer bytes (" + std::to_string(bytes.size()) + ") than an object header (96)";
        return r;
    }
    ObjectHeader h;
    std::memcpy(&h, bytes.data(), sizeof h);
    if (h.magic != kObjectMagic) {
        r.error = "no engine object here (magic mismatch)";
        return r;
    }
    if (h.format_version != kFormatVersion) {
        r.error = "object format version " + std::to_string(h.format_version) + " is not " +
                  std::to_string(kFormatVersion);
        return r;
    }
    if (h.object_type != uint8_t(ObjectType::kTriangleCluster) &&
        h.object_type != uint8_t(ObjectType::kTriangleClusterTemplate)) {
        r.error = "object type " + std::to_string(h.object_type) +
                  " is not a cluster or a cluster template";
        return r;
    }
    if (h.object_size < sizeof(ObjectHeader) || h.object_size > bytes.size()) {
        r.error = "object size " + std::to_string(h.object_size) + " does not fit the " +
                  std::to_string(bytes.size()) + " bytes available";
        return r;
    }
    const uint32_t n_triangles = h.triangle_count, n_vertices = h.vertex_count;
    if (n_triangles > detail::kMaxTriangles || n_vertices > detail::kMaxVertices ||
        h.position_truncate_bits > 32 || h.position_bits != 32 - h.position_truncate_bits) {
        r.error = "counts or position bits out of range";
        return r;
    }
    const uint32_t s = h.object_size;
    bool ok = section_fits(h.indices_offset, 3ull * n_triangles, s);
    if (h.header_flags & kHasPositions)
        ok &= section_fits(h.positions_offset,
                           detail::packed_section_size(n_vertices, h.position_bits), s);
    if (h.header_flags & kHasTriangleOrder)
        ok &= section_fits(h.triangle_order_offset, n_triangles, s);
    if (h.header_flags & kHasTriangleData)
        ok &= section_fits(h.triangle_data_offset, 4ull * n_triangles, s);
    if (h.header_flags & kHasOpacityMicromap)
        ok &= section_fits(h.omm_offset, sizeof(OpacityMicromapSection) + 4ull * n_triangles, s);
    if (h.header_flags & kHasBoundsLimit) ok &= section_fits(h.bounds_limit_offset, 24, s);
    if (h.node_count)
        ok &= section_fits(h.nodes_offset, 8ull * h.node_count, s) &&
              (h.header_flags & kHasPositions) && h.node_count <= detail::kMaxNodes;
    if (!ok) {
        r.error = "a section lies outside the object";
        return r;
    }
    // Local indices must name stored vertices, and BVH links must stay inside the object,
    // so that tracing a corrupt object can never read out of bounds.
    // (A cluster without vertices keeps its inactive triangles' indices at 0 and has no BVH.)
    if (n_vertices == 0 && h.node_count != 0) {
        r.error = "BVH over a cluster without vertices";
        return r;
    }
    const std::byte* idx = bytes.data() + h.indices_offset;
    for (uint32_t i = 0; i < 3 * n_triangles; ++i)
        if (uint32_t(idx[i]) >= (n_vertices ? n_vertices : 1)) {
            r.error = "local index " + std::to_string(uint32_t(idx[i])) + " >= vertex count " +
                      std::to_string(n_vertices);
            return r;
        }
    bool referenced[detail::kMaxNodes] = {};
    for (uint32_t i = 0; i < h.node_count; ++i) {
        BvhNode n;
        std::memcpy(&n, bytes.data() + h.nodes_offset + 8 * i, 8);
        if (n.link & kLeafBit) {
            const uint32_t first = n.link & 0xFF, count = ((n.link >> 8) & 3) + 1;
            if (first + count > n_triangles) {
                r.error =
                    "BVH leaf " + std::to_string(i) + " names triangles beyond the triangle count";
                return r;
            }
        } else {
            // Children after their parent and each node reached once: traversal is a tree walk.
            const uint32_t left = n.link & 0x3FF;
            if (left <= i || left + 1u >= h.node_count || referenced[left] ||
                referenced[left + 1]) {
                r.error = "BVH node " + std::to_string(i) +
                          " links outside the node array or to a shared child";
                return r;
            }
            referenced[left] = referenced[left + 1] = true;
        }
    }
    r.header = h;
    return r;
}

uint32_t object_size_from_header(std::span<const std::byte> bytes) {
    if (bytes.size() < sizeof(ObjectHeader)) return 0;
    ObjectHeader h;
    std::memcpy(&h, bytes.data(), sizeof h);
    if (h.magic != kObjectMagic || h.format_version != kFormatVersion) return 0;
    return h.object_size;
}

void decode_position(std::span<const std::byte> object, const ObjectHeader& h, uint32_t vertex,
                     float xyz[3]) {
    if (!(h.header_flags & kHasPositions) || vertex >= h.vertex_count) {
        xyz[0] = xyz[1] = xyz[2] = 0.0f;
        return;
    }
    const std::byte* sec = object.data() + h.positions_offset;
    const uint32_t size = detail::packed_section_size(h.vertex_count, h.position_bits);
    for (uint32_t k = 0; k < 3; ++k)
        xyz[k] = detail::unpack_coordinate(sec, size, h.position_bits, h.position_truncate_bits,
                                           3 * vertex + k);
}

DecodedTriangle decode_triangle(std::span<const std::byte> object, const ObjectHeader& h,
                                uint32_t i) {
    DecodedTriangle d{};
    const std::byte* base = object.data();
    for (int v = 0; v < 3; ++v) {
        d.local_indices[v] = uint8_t(base[h.indices_offset + 3 * i + v]);
        decode_position(object, h, d.local_indices[v], d.v[v]);
    }
    d.original_index = (h.header_flags & kHasTriangleOrder)
                           ? uint32_t(uint8_t(base[h.triangle_order_offset + i]))
                           : i;
    d.geometry_index_and_flags = (h.header_flags & kHasTriangleData)
                                     ? detail::read_u32(base + h.triangle_data_offset + 4 * i)
                                     : h.base_geometry_index_and_flags;
    return d;
}

}  // namespace clastrace::engine
