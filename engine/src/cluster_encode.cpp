// Lays out a CLAS or template object (docs/engine-formats.md) from decoded input.
#include "cluster_internal.h"

#include <algorithm>
#include <bit>
#include <cmath>

namespace clastrace::engine::detail {

namespace {

bool finite3(const float v[3]) { return std::isfinite(v[0]) && std::isfinite(v[1]) && std::isfinite(v[2]); }

// Packs each coordinate's top `bits` bits (the truncated low bits are zero) into a
// little-endian bit stream.
void pack_positions(const float* positions, uint32_t count, uint32_t bits, uint32_t truncate, std::byte* dst) {
  if (bits == 32) {
    std::memcpy(dst, positions, size_t(count) * 4);
    return;
  }
  if (bits == 0) return;
  uint64_t acc = 0;
  uint32_t acc_bits = 0;
  size_t out = 0;
  for (uint32_t i = 0; i < count; ++i) {
    const uint32_t pattern = std::bit_cast<uint32_t>(positions[i]) >> truncate;
    acc |= uint64_t(pattern) << acc_bits;
    acc_bits += bits;
    while (acc_bits >= 8) {
      dst[out++] = std::byte(acc & 0xFF);
      acc >>= 8;
      acc_bits -= 8;
    }
  }
  if (acc_bits > 0) dst[out++] = std::byte(acc & 0xFF);
}

// The first guess may be off by one either way (inv_step is rounded); the loops make it
// conservative with the exact decoding traversal uses.
uint8_t quantize_lo(const QuantFrame& f, const float inv_step[3], int a, float v) {
  const float rel = (v - f.lo[a]) * inv_step[a];
  int q = rel >= 255.0f ? 255 : (rel > 0.0f ? int(rel) : 0);
  while (q > 0 && dequant_lo(f, a, uint32_t(q)) > v) --q;
  return uint8_t(q);
}

uint8_t quantize_hi(const QuantFrame& f, const float inv_step[3], int a, float v) {
  const float rel = (v - f.lo[a]) * inv_step[a];
  // ceil of rel in (0, 255) as truncation plus one when rel has a fraction (exact there,
  // and no libm call on baseline x86-64, which lacks roundss).
  int q = 0;
  if (rel >= 255.0f) q = 255;
  else if (rel > 0.0f) {
    q = int(rel);
    q += float(q) < rel;
  }
  while (q < 255 && dequant_hi(f, a, uint32_t(q)) < v) ++q;
  return uint8_t(q);
}

}  // namespace

uint32_t encode_object(const EncodeInput& in, BvhScratch& s, std::vector<std::byte>& out) {
  ObjectHeader h{};
  h.magic = kObjectMagic;
  h.object_type = uint8_t(in.type);
  h.format_version = kFormatVersion;
  h.cluster_id = in.cluster_id;
  h.triangle_count = uint16_t(in.triangle_count);
  h.vertex_count = uint16_t(in.vertex_count);
  h.position_truncate_bits = uint8_t(in.truncate_bits);
  h.position_bits = uint8_t(32 - in.truncate_bits);
  h.cluster_flags = uint8_t(in.cluster_flags);
  h.base_geometry_index_and_flags = in.base_geometry_index_and_flags;
  h.vertex_format = in.vertex_format;
  const uint32_t T = in.triangle_count;
  const bool is_clas = in.type == ObjectType::TriangleCluster;

  // Active triangles: indices in range and no NaN coordinate (after truncation). NaN is
  // decided per vertex and bounds are taken over the vertices active triangles use, so
  // the per-triangle work stays at three byte loads.
  uint8_t active[kMaxTriangles];
  uint32_t n_active = 0;
  bool any_nan = false;
  float bmin[3] = {INFINITY, INFINITY, INFINITY}, bmax[3] = {-INFINITY, -INFINITY, -INFINITY};
  if (in.positions) {
    uint8_t vertex_nan[kMaxVertices];
    uint8_t vertex_used[kMaxVertices] = {};
    for (uint32_t v = 0; v < in.vertex_count; ++v) {
      const float* p = in.positions + 3 * v;
      vertex_nan[v] = (p[0] != p[0]) | (p[1] != p[1]) | (p[2] != p[2]);  // NaN, branch-free
    }
    for (uint32_t t = 0; t < T; ++t) {
      if (in.inactive && in.inactive[t]) continue;
      const uint32_t* tri = in.indices + 3 * t;
      if (vertex_nan[tri[0]] | vertex_nan[tri[1]] | vertex_nan[tri[2]]) {
        any_nan = true;
        continue;
      }
      active[n_active++] = uint8_t(t);
      vertex_used[tri[0]] = vertex_used[tri[1]] = vertex_used[tri[2]] = 1;
    }
    for (uint32_t v = 0; v < in.vertex_count; ++v) {
      if (!vertex_used[v]) continue;
      const float* p = in.positions + 3 * v;
      for (int k = 0; k < 3; ++k) {
        bmin[k] = std::min(bmin[k], p[k]);
        bmax[k] = std::max(bmax[k], p[k]);
      }
    }
  }
  if (n_active == 0) {
    for (int k = 0; k < 3; ++k) bmin[k] = bmax[k] = 0.0f;
  }
  std::memcpy(h.bounds_min, bmin, sizeof bmin);
  std::memcpy(h.bounds_max, bmax, sizeof bmax);

  // Triangle order: BVH order for a CLAS (inactive triangles after the active ones),
  // the application's order for a template.
  uint8_t order[kMaxTriangles];
  uint32_t n_nodes = 0;
  if (is_clas && n_active > 0) {
    build_bvh(in.positions, in.indices, active, n_active, s);
    n_nodes = s.node_count;
    std::memcpy(order, s.perm, n_active);
    bool is_active[kMaxTriangles] = {};
    for (uint32_t i = 0; i < n_active; ++i) is_active[active[i]] = true;
    uint32_t k = n_active;
    for (uint32_t t = 0; t < T; ++t)
      if (!is_active[t]) order[k++] = uint8_t(t);
  } else {
    for (uint32_t t = 0; t < T; ++t) order[t] = uint8_t(t);
  }
  bool identity = true;
  for (uint32_t t = 0; t < T; ++t) identity &= order[t] == t;

  bool varying = false;
  uint32_t max_geometry_index = in.base_geometry_index_and_flags & 0xFFFFFFu;
  if (in.geometry_index_and_flags && T > 0) {
    max_geometry_index = 0;
    for (uint32_t t = 0; t < T; ++t) {
      varying |= in.geometry_index_and_flags[t] != in.geometry_index_and_flags[0];
      max_geometry_index = std::max(max_geometry_index, in.geometry_index_and_flags[t] & 0xFFFFFFu);
    }
    if (!varying) h.base_geometry_index_and_flags = in.geometry_index_and_flags[0];
  }
  h.max_geometry_index = max_geometry_index;

  const QuantFrame frame = make_frame(bmin, bmax);
  bool unbounded = !finite3(bmin) || !finite3(bmax);
  for (int a = 0; a < 3; ++a) unbounded |= !std::isfinite(frame.step[a]);

  // Layout.
  uint32_t size = sizeof(ObjectHeader);
  if (n_nodes) {
    h.nodes_offset = size;
    h.node_count = uint16_t(n_nodes);
    size += 8 * n_nodes;
  }
  const uint32_t pos_bytes = in.positions ? packed_section_size(in.vertex_count, h.position_bits) : 0;
  if (in.positions) {
    h.header_flags |= kHasPositions;
    h.positions_offset = size;
    size = align4(size + pos_bytes);
  }
  h.indices_offset = size;
  size += 3 * T;
  if (!identity) {
    h.header_flags |= kHasTriangleOrder;
    h.triangle_order_offset = size;
    size += T;
  }
  size = align4(size);
  if (varying) {
    h.header_flags |= kHasTriangleData;
    h.triangle_data_offset = size;
    size += 4 * T;
  }
  if (in.has_omm) {
    h.header_flags |= kHasOpacityMicromap;
    size = (size + 7u) & ~7u;
    h.omm_offset = size;
    size += sizeof(OpacityMicromapSection) + 4 * T;
  }
  if (in.has_bounds_limit) {
    h.header_flags |= kHasBoundsLimit;
    h.bounds_limit_offset = size;
    size += 24;
  }
  if (unbounded) h.header_flags |= kUnboundedNodes;
  if (any_nan) h.header_flags |= kHasNaNTriangles;
  size = align4(size);
  h.object_size = size;

  out.assign(size, std::byte{0});
  std::byte* base = out.data();
  std::memcpy(base, &h, sizeof h);

  float inv_step[3];
  for (int a = 0; a < 3; ++a) inv_step[a] = 1.0f / frame.step[a];
  for (uint32_t i = 0; i < n_nodes; ++i) {
    const BvhScratch::Node& sn = s.nodes[i];
    BvhNode node{};
    for (int a = 0; a < 3; ++a) {
      if (unbounded) {
        node.qmin[a] = 0;
        node.qmax[a] = 255;
      } else {
        node.qmin[a] = quantize_lo(frame, inv_step, a, sn.lo[a]);
        node.qmax[a] = quantize_hi(frame, inv_step, a, sn.hi[a]);
      }
    }
    node.link = sn.count ? uint16_t(kLeafBit | ((sn.count - 1u) << 8) | sn.first) : uint16_t(sn.first);
    std::memcpy(base + h.nodes_offset + 8 * i, &node, 8);
  }
  if (in.positions) pack_positions(in.positions, 3 * in.vertex_count, h.position_bits, in.truncate_bits, base + h.positions_offset);
  std::byte* const index_bytes = base + h.indices_offset;
  for (uint32_t i = 0; i < T; ++i) {
    const uint32_t t = order[i];
    if (!(in.inactive && in.inactive[t]))
      for (int v = 0; v < 3; ++v) index_bytes[3 * i + v] = std::byte(uint8_t(in.indices[3 * t + v]));  // dead ones stay 0
    if (!identity) base[h.triangle_order_offset + i] = std::byte(uint8_t(t));
    if (varying) std::memcpy(base + h.triangle_data_offset + 4 * i, &in.geometry_index_and_flags[t], 4);
    if (in.has_omm) std::memcpy(base + h.omm_offset + sizeof(OpacityMicromapSection) + 4 * i, &in.omm_indices[t], 4);
  }
  if (in.has_omm) {
    OpacityMicromapSection sec{};
    sec.opacity_micromap_array = in.omm_array;
    sec.index_type = in.omm_index_type;
    std::memcpy(base + h.omm_offset, &sec, sizeof sec);
  }
  if (in.has_bounds_limit) std::memcpy(base + h.bounds_limit_offset, in.bounds_limit, 24);
  return size;
}

}  // namespace clastrace::engine::detail
