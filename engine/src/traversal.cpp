// SPDX-License-Identifier: Apache-2.0
// Ray traversal of one CLAS: the engine's conservative slab test over the quantized BVH,
// its watertight triangle test (geometry/).
#include "clastrace/engine/traversal.h"

#include "cluster_internal.h"
#include "geometry/slab.h"
#include "geometry/triangle.h"
#include "clastrace/vk_cluster_abi.h"

#include <cmath>
#include <cstring>
#include <limits>

namespace clastrace::engine {

namespace {

geometry::PreparedRay prepare(const Ray& ray, TraversalMode mode) {
    const double o[3] = {ray.origin[0], ray.origin[1], ray.origin[2]};
    const double d[3] = {ray.direction[0], ray.direction[1], ray.direction[2]};
    return geometry::prepare_ray(o, d, ray.tmin, ray.tmax, mode);
}

// Widens a best-hit distance for box culling: a box entered exactly at the best t (a hit on a
// vertex or edge lying on its face) may round its entry just past it, and the tie with a lower
// triangle index inside it must still be found. 2^-20 is far above the slab tests' rounding.
double cull_distance(double tmax) { return tmax + std::fabs(tmax) * 0x1p-20; }

// The triangles of one checked CLAS and the rules that turn a triangle hit into a Hit (flags,
// facing, opacity), shared by the BVH walk and the exhaustive reference.
template <bool KPlainFloats>
struct ClasTriangles {
    const ObjectHeader& h;
    const std::byte* base;
    const std::byte* pos;
    const std::byte* idx;
    // Bytes readable from the positions section on: the rest of the object. Reading past the
    // section's last coordinate (into the next section) only fetches bits the mask drops,
    // and spares the short-read path for all but the object's last bytes.
    uint32_t pos_size;

    explicit ClasTriangles(const ClasView& clas)
        : h(clas.header),
          base(clas.bytes.data()),
          pos(base + h.positions_offset),
          idx(base + h.indices_offset),
          pos_size(h.object_size - h.positions_offset) {}

    // Stored triangle `i` (BVH order) hit within [tmin, tmax] and accepted by the ray flags:
    // fills `out` (t as double in `t`).
    bool accept(uint32_t i, const geometry::PreparedRay& r, uint32_t ray_flags, double tmax,
                Hit* out, double* t) const {
        float v[3][3];
        for (int k = 0; k < 3; ++k) {
            const uint32_t vi = uint8_t(idx[3 * i + k]);
            if constexpr (KPlainFloats) {
                std::memcpy(v[k], pos + 12 * size_t(vi), 12);
            } else if (h.position_bits == 0) {
                v[k][0] = v[k][1] = v[k][2] = 0.0f;
            } else {
                detail::unpack_vertex(pos, pos_size, h.position_bits, h.position_truncate_bits, vi,
                                      v[k]);
            }
        }
        geometry::TriangleHit th;
        if (!geometry::intersect_triangle(r, v[0], v[1], v[2], tmax, &th)) return false;
        const uint32_t gif = (h.header_flags & kHasTriangleData)
                                 ? detail::read_u32(base + h.triangle_data_offset + 4 * i)
                                 : h.base_geometry_index_and_flags;
        const uint32_t gflags = gif >> 29;
        const bool cull_disable =
            gflags & VK_CLUSTER_ACCELERATION_STRUCTURE_GEOMETRY_CULL_DISABLE_BIT_NV;
        if (!cull_disable) {
            if ((ray_flags & kRayFlagCullBackFacingTriangles) && !th.front) return false;
            if ((ray_flags & kRayFlagCullFrontFacingTriangles) && th.front) return false;
        }
        bool opaque = gflags & VK_CLUSTER_ACCELERATION_STRUCTURE_GEOMETRY_OPAQUE_BIT_NV;
        if (ray_flags & kRayFlagOpaque)
            opaque = true;
        else if (ray_flags & kRayFlagNoOpaque)
            opaque = false;
        if ((ray_flags & kRayFlagCullOpaque) && opaque) return false;
        if ((ray_flags & kRayFlagCullNoOpaque) && !opaque) return false;
        out->hit = true;
        out->t = float(th.t);
        out->u = float(th.u);
        out->v = float(th.v);
        out->uv_error = float(th.uv_error);
        out->triangle_index = (h.header_flags & kHasTriangleOrder)
                                  ? uint32_t(uint8_t(base[h.triangle_order_offset + i]))
                                  : i;
        out->cluster_id = h.cluster_id;
        out->geometry_index = gif & 0xFFFFFFu;
        out->front_face = th.front;
        out->opaque = opaque;
        *t = th.t;
        return true;
    }
};

// Whether a hit at `t` on stored triangle `i` replaces the best so far (at `best_t`, stored
// triangle `best_i`): strictly closer, or as close and earlier in the stored order, so that the
// answer does not depend on the order the walk visits leaves in.
inline bool replaces(bool have_best, double t, uint32_t i, double best_t, uint32_t best_i) {
    return !have_best || t < best_t || (t == best_t && i < best_i);
}

template <bool KAny, bool KPlainFloats>
Hit traverse_impl(const ClasView& clas, const Ray& ray, uint32_t ray_flags, TraversalMode mode) {
    Hit best;
    const ObjectHeader& h = clas.header;
    if (h.node_count == 0) return best;
    const geometry::PreparedRay r = prepare(ray, mode);
    if (!(r.tmin <= r.tmax)) return best;
    const ClasTriangles<KPlainFloats> tris(clas);
    const std::byte* nodes = tris.base + h.nodes_offset;
    const bool unbounded = h.header_flags & kUnboundedNodes;
    const detail::QuantFrame frame = detail::make_frame(h.bounds_min, h.bounds_max);
    const bool first_hit = KAny || (ray_flags & kRayFlagTerminateOnFirstHit);

    double tmax = r.tmax;
    uint32_t best_i = 0;
    // Each entry carries the distance at which the ray enters its box (tested with its
    // sibling): popping it compares that with the best hit since, with no second box test.
    struct Entry {
        uint16_t node;
        double entry;
    };
    Entry stack[detail::kMaxNodes + 1];
    int sp = 0;
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
        stack[sp++] = Entry{0, tn};
    }
    while (sp > 0) {
        const Entry e = stack[--sp];
        const double cull = best.hit ? cull_distance(tmax) : tmax;
        if (e.entry > cull) continue;
        BvhNode n;
        std::memcpy(&n, nodes + 8 * size_t(e.node), 8);
        if (n.link & kLeafBit) {
            const uint32_t first = n.link & 0xFF, count = ((n.link >> 8) & 3) + 1;
            for (uint32_t i = first; i < first + count; ++i) {
                Hit hit;
                double t;
                if (!tris.accept(i, r, ray_flags, tmax, &hit, &t)) continue;
                if (!KAny && !replaces(best.hit, t, i, tmax, best_i)) continue;
                best = hit;
                best_i = i;
                tmax = t;
                if (first_hit) return best;
            }
            continue;
        }
        const uint32_t left = n.link & 0x3FF;
        float llo[3], lhi[3], rlo[3], rhi[3];
        double tl, tr;
        node_box(left, llo, lhi);
        node_box(left + 1, rlo, rhi);
        const bool hl = geometry::slab_test<true>(r, llo, lhi, cull, &tl);
        const bool hr = geometry::slab_test<true>(r, rlo, rhi, cull, &tr);
        if (hl && hr) {
            if (tl <= tr) {
                stack[sp++] = Entry{uint16_t(left + 1), tr};
                stack[sp++] = Entry{uint16_t(left), tl};
            } else {
                stack[sp++] = Entry{uint16_t(left), tl};
                stack[sp++] = Entry{uint16_t(left + 1), tr};
            }
        } else if (hl) {
            stack[sp++] = Entry{uint16_t(left), tl};
        } else if (hr) {
            stack[sp++] = Entry{uint16_t(left + 1), tr};
        }
    }
    return best;
}

// Every stored triangle tested, no box: the reference the walk above must agree with.
template <bool KPlainFloats>
Hit exhaustive_impl(const ClasView& clas, const Ray& ray, uint32_t ray_flags, TraversalMode mode) {
    Hit best;
    const geometry::PreparedRay r = prepare(ray, mode);
    if (!(r.tmin <= r.tmax) || clas.header.node_count == 0) return best;
    const ClasTriangles<KPlainFloats> tris(clas);
    double tmax = r.tmax;
    uint32_t best_i = 0;
    for (uint32_t i = 0; i < clas.header.triangle_count; ++i) {
        Hit hit;
        double t;
        if (!tris.accept(i, r, ray_flags, tmax, &hit, &t)) continue;
        if (!replaces(best.hit, t, i, tmax, best_i)) continue;
        best = hit;
        best_i = i;
        tmax = t;
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

Hit trace_closest_exhaustive(const ClasView& clas, const Ray& ray, uint32_t ray_flags,
                             TraversalMode mode) {
    return clas.header.position_bits == 32 ? exhaustive_impl<true>(clas, ray, ray_flags, mode)
                                           : exhaustive_impl<false>(clas, ray, ray_flags, mode);
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
