// SPDX-License-Identifier: Apache-2.0
// Ray traversal of one CLAS: the engine's conservative slab test over the quantized BVH,
// its watertight triangle test (geometry/).
#include "clastrace/engine/traversal.h"

#include "cluster_internal.h"
#include "geometry/slab.h"
#include "geometry/triangle.h"
#include "clastrace/vk_cluster_abi.h"

#include <cmath>
#include <limits>

namespace clastrace::engine {

namespace {

geometry::PreparedRay prepare(const Ray& ray, TraversalMode mode) {
    const double o[3] = {ray.origin[0], ray.origin[1], ray.origin[2]};
    const double d[3] = {ray.direction[0], ray.direction[1], ray.direction[2]};
    return geometry::prepare_ray(o, d, ray.tmin, ray.tmax, mode);
}

template <bool KAny, bool KPlainFloats>
Hit traverse_impl(const ClasView& clas, const Ray& ray, uint32_t ray_flags, TraversalMode mode) {
    Hit best;
    const ObjectHeader& h = clas.header;
    if (h.node_count == 0) return best;
    const geometry::PreparedRay r = prepare(ray, mode);
    if (!(r.tmin <= r.tmax)) return best;
    const std::byte* base = clas.bytes.data();
    const std::byte* nodes = base + h.nodes_offset;
    const std::byte* pos = base + h.positions_offset;
    const std::byte* idx = base + h.indices_offset;
    // Bytes readable from the positions section on: the rest of the object. Reading past the
    // section's last coordinate (into the next section) only fetches bits the mask drops,
    // and spares the short-read path for all but the object's last bytes.
    const uint32_t pos_size = h.object_size - h.positions_offset;
    const bool unbounded = h.header_flags & kUnboundedNodes;
    const detail::QuantFrame frame = detail::make_frame(h.bounds_min, h.bounds_max);
    const bool first_hit = KAny || (ray_flags & kRayFlagTerminateOnFirstHit);

    double tmax = r.tmax;
    uint16_t stack[detail::kMaxNodes + 1];
    int sp = 0;
    stack[sp++] = 0;
    auto node_box = [&](uint32_t i, float lo[3], float hi[3]) {
        BvhNode n;
        std::memcpy(&n, nodes + 8 * size_t(i), 8);
        for (int a = 0; a < 3; ++a) {
            if (unbounded) {
                lo[a] = -INFINITY;
                hi[a] = INFINITY;
            } else {
                lo[a] = detail::dequant_lo(frame, a, n.qmin[a]);
                hi[a] = detail::dequant_hi(frame, a, n.qmax[a]);
            }
        }
        return n.link;
    };
    {
        float lo[3], hi[3];
        double tn;
        node_box(0, lo, hi);
        if (!geometry::slab_test<true>(r, lo, hi, tmax, &tn)) return best;
    }
    while (sp > 0) {
        const uint32_t ni = stack[--sp];
        BvhNode n;
        std::memcpy(&n, nodes + 8 * size_t(ni), 8);
        if (n.link & kLeafBit) {
            const uint32_t first = n.link & 0xFF, count = ((n.link >> 8) & 3) + 1;
            for (uint32_t i = first; i < first + count; ++i) {
                float v[3][3];
                for (int k = 0; k < 3; ++k) {
                    const uint32_t vi = uint8_t(idx[3 * i + k]);
                    if constexpr (KPlainFloats) {
                        std::memcpy(v[k], pos + 12 * size_t(vi), 12);
                    } else {
                        if (h.position_bits == 0) {
                            v[k][0] = v[k][1] = v[k][2] = 0.0f;
                        } else {
                            detail::unpack_vertex(pos, pos_size, h.position_bits,
                                                  h.position_truncate_bits, vi, v[k]);
                        }
                    }
                }
                geometry::TriangleHit th;
                if (!geometry::intersect_triangle(r, v[0], v[1], v[2], tmax, &th)) continue;
                if (!KAny && th.t >= tmax && best.hit) continue;
                const uint32_t gif = (h.header_flags & kHasTriangleData)
                                         ? detail::read_u32(base + h.triangle_data_offset + 4 * i)
                                         : h.base_geometry_index_and_flags;
                const uint32_t gflags = gif >> 29;
                const bool cull_disable =
                    gflags & VK_CLUSTER_ACCELERATION_STRUCTURE_GEOMETRY_CULL_DISABLE_BIT_NV;
                if (!cull_disable) {
                    if ((ray_flags & kRayFlagCullBackFacingTriangles) && !th.front) continue;
                    if ((ray_flags & kRayFlagCullFrontFacingTriangles) && th.front) continue;
                }
                bool opaque = gflags & VK_CLUSTER_ACCELERATION_STRUCTURE_GEOMETRY_OPAQUE_BIT_NV;
                if (ray_flags & kRayFlagOpaque)
                    opaque = true;
                else if (ray_flags & kRayFlagNoOpaque)
                    opaque = false;
                if ((ray_flags & kRayFlagCullOpaque) && opaque) continue;
                if ((ray_flags & kRayFlagCullNoOpaque) && !opaque) continue;
                best.hit = true;
                best.t = float(th.t);
                best.u = float(th.u);
                best.v = float(th.v);
                best.uv_error = float(th.uv_error);
                best.triangle_index = (h.header_flags & kHasTriangleOrder)
                                          ? uint32_t(uint8_t(base[h.triangle_order_offset + i]))
                                          : i;
                best.cluster_id = h.cluster_id;
                best.geometry_index = gif & 0xFFFFFFu;
                best.front_face = th.front;
                best.opaque = opaque;
                tmax = th.t;
                if (first_hit) return best;
            }
            continue;
        }
        const uint32_t left = n.link & 0x3FF;
        float llo[3], lhi[3], rlo[3], rhi[3];
        double tl, tr;
        node_box(left, llo, lhi);
        node_box(left + 1, rlo, rhi);
        const bool hl = geometry::slab_test<true>(r, llo, lhi, tmax, &tl);
        const bool hr = geometry::slab_test<true>(r, rlo, rhi, tmax, &tr);
        if (hl && hr) {
            if (tl <= tr) {
                stack[sp++] = uint16_t(left + 1);
                stack[sp++] = uint16_t(left);
            } else {
                stack[sp++] = uint16_t(left);
                stack[sp++] = uint16_t(left + 1);
            }
        } else if (hl) {
            stack[sp++] = uint16_t(left);
        } else if (hr) {
            stack[sp++] = uint16_t(left + 1);
        }
    }
    return best;
}

template <bool KAny>
Hit traverse(const ClasView& clas, const Ray& ray, uint32_t ray_flags, TraversalMode mode) {
    return clas.header.position_bits == 32 ? traverse_impl<KAny, true>(clas, ray, ray_flags, mode)
                                           : traverse_impl<KAny, false>(clas, ray, ray_flags, mode);
}

}  // namespace

const char* traversal_mode_name(TraversalMode mode) {
    return mode == TraversalMode::kFloat32 ? "float32" : "double";
}

std::optional<ClasView> open_clas(std::span<const std::byte> bytes, std::string* error) {
    HeaderCheck hc = read_object_header(bytes);
    if (hc.header && hc.header->object_type != uint8_t(ObjectType::kTriangleCluster)) {
        hc.header.reset();
        hc.error = "object is a cluster template, not a CLAS";
    }
    if (!hc.header) {
        if (error) *error = hc.error;
        return std::nullopt;
    }
    return ClasView{bytes.first(hc.header->object_size), *hc.header};
}

Hit trace_closest(const ClasView& clas, const Ray& ray, uint32_t ray_flags, TraversalMode mode) {
    return traverse<false>(clas, ray, ray_flags, mode);
}
bool trace_any(const ClasView& clas, const Ray& ray, uint32_t ray_flags, TraversalMode mode) {
    return traverse<true>(clas, ray, ray_flags, mode).hit;
}

Hit trace_closest(std::span<const std::byte> clas, const Ray& ray, uint32_t ray_flags,
                  TraversalMode mode) {
    const auto view = open_clas(clas);
    return view ? trace_closest(*view, ray, ray_flags, mode) : Hit{};
}
bool trace_any(std::span<const std::byte> clas, const Ray& ray, uint32_t ray_flags,
               TraversalMode mode) {
    const auto view = open_clas(clas);
    return view ? trace_any(*view, ray, ray_flags, mode) : false;
}

}  // namespace clastrace::engine
