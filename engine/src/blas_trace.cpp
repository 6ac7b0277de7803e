// SPDX-License-Identifier: Apache-2.0
// BLAS -> CLAS traversal: the engine's conservative slab test (geometry/slab.h) per BVH
// node, then the CLAS traversal (traversal.h) per referenced cluster. Children are visited nearest
// first; a hit replaces the best when closer, or as close through a lower reference index, so
// ties do not depend on the visiting order (trace_bottom_level_bytes_exhaustive is the
// reference).
#include "clastrace/engine/blas.h"

#include "geometry/slab.h"
#include "spill_stack.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <sstream>

namespace clastrace::engine {
namespace {

bool hit_box(const geometry::PreparedRay& r, const BottomLevelNode& n, double tmax, double& entry) {
    return geometry::slab_test<true>(r, n.bounds_min, n.bounds_max, tmax, &entry);
}

// The distance boxes are culled at once a hit at `tmax` is held: a cluster entered exactly there
// (the hit on its box's face) may round its entry just past it and still hold the tie with the
// lower reference index. 2^-20 is far above the slab test's rounding.
double cull_distance(double tmax) { return tmax + std::fabs(tmax) * 0x1p-20; }

// Whether `h` through reference `ref` replaces `best`: closer, or as close through a lower
// reference index.
bool replaces(const BottomLevelHit& best, const Hit& h, const ClusterReference& ref) {
    if (!h.hit) return false;
    if (!best.hit.hit || h.t < best.hit.t) return true;
    return h.t == best.hit.t && ref.reference_index < best.reference_index;
}

// The ray a CLAS is traced with once a hit at `best` is held: up to the float after it, so
// that a hit whose float t ties the best is still found whatever its double t (the tie rule
// above then decides).
Ray clipped_ray(const Ray& ray, const BottomLevelHit& best) {
    Ray r = ray;
    if (best.hit.hit) r.tmax = std::min(ray.tmax, std::nextafter(best.hit.t, INFINITY));
    return r;
}

// A CLAS as clas_at gives it: bytes checked on each trace, or a view checked once.
bool absent(std::span<const std::byte> clas) { return clas.empty(); }
bool absent(const ClasView* clas) { return clas == nullptr; }
Hit trace_clas(std::span<const std::byte> clas, const Ray& ray, uint32_t flags,
               TraversalMode mode) {
    return trace_closest(clas, ray, flags, mode);
}
Hit trace_clas(const ClasView* clas, const Ray& ray, uint32_t flags, TraversalMode mode) {
    return trace_closest(*clas, ray, flags, mode);
}

// Walks a checked BLAS (`blas` holds the whole object): `clas_at(reference)` gives the bytes
// of the CLAS a reference names (empty: skipped); `visit(clas, reference, tmax)` returns false
// to stop.
template <class ClasAt, class Visit>
void walk_bytes(std::span<const std::byte> blas, const Ray& ray, TraversalMode mode,
                ClasAt&& clas_at, Visit&& visit) {
    BottomLevelHeader h;
    std::memcpy(&h, blas.data(), sizeof h);
    if (h.node_count == 0) return;
    auto node_at = [&](uint32_t i) {
        BottomLevelNode n;
        std::memcpy(&n, blas.data() + h.nodes_offset + uint64_t(i) * sizeof n, sizeof n);
        return n;
    };
    const double origin[3] = {ray.origin[0], ray.origin[1], ray.origin[2]};
    const double direction[3] = {ray.direction[0], ray.direction[1], ray.direction[2]};
    const geometry::PreparedRay rb =
        geometry::prepare_ray(origin, direction, ray.tmin, ray.tmax, mode);
    // Each entry carries the distance at which the ray enters its box, tested when its parent
    // was: popping it only compares that with the best hit since (the same verdict as testing
    // the box again with the lowered tmax, at no second slab test). A fixed stack covers the
    // trees the builder makes; deeper (checked, hostile) ones spill into the vector.
    struct Entry {
        uint32_t node;
        double entry;
    };
    Entry entries[128];
    std::vector<Entry> overflow;
    SpillStack<Entry, 128> stack(entries, &overflow);
    auto push = [&](uint32_t node, double entry) { stack.push(Entry{node, entry}); };
    double tmax = ray.tmax;
    bool have_hit = false;
    {
        double entry;
        if (hit_box(rb, node_at(0), tmax, entry)) push(0, entry);
    }
    while (!stack.empty()) {
        const Entry e = stack.pop();
        const double cull = have_hit ? cull_distance(tmax) : tmax;
        if (e.entry > cull) continue;
        const BottomLevelNode n = node_at(e.node);
        if (n.count == 0) {
            BottomLevelNode l = node_at(n.first), r = node_at(n.first + 1);
            double el = 0, er = 0;
            bool hl = hit_box(rb, l, cull, el), hr = hit_box(rb, r, cull, er);
            if (hl && hr) {
                if (el <= er) {
                    push(n.first + 1, er);
                    push(n.first, el);
                } else {
                    push(n.first, el);
                    push(n.first + 1, er);
                }
            } else if (hl) {
                push(n.first, el);
            } else if (hr) {
                push(n.first + 1, er);
            }
            continue;
        }
        for (uint32_t k = 0; k < n.count; ++k) {
            ClusterReference ref;
            std::memcpy(&ref,
                        blas.data() + h.references_offset + uint64_t(n.first + k) * sizeof ref,
                        sizeof ref);
            const auto clas = clas_at(ref);
            if (absent(clas)) continue;
            const double before = tmax;
            if (!visit(clas, ref, tmax)) return;
            have_hit |= tmax != before;
        }
    }
}

// The BLAS at `blas_address` in memory, its CLAS judged by `directory` (or by their bytes).
template <class Visit>
void walk(const MemoryImage& memory, uint64_t blas_address, const Ray& ray, TraversalMode mode,
          const ObjectDirectory* directory, std::vector<Finding>* findings, Visit&& visit) {
    ObjectDirectory empty;
    const ObjectDirectory& dir = directory ? *directory : empty;
    FieldRef where{"trace.blas", -1};
    ObjectLookup blas =
        dir.lookup(memory, blas_address, ObjectType::kClustersBottomLevel, false, where);
    if (!blas.found()) {
        if (findings)
            findings->push_back({kRuleNotABottomLevel, "trace: " + blas.error, -1, blas_address});
        return;
    }
    std::vector<uint32_t> reported;
    auto clas_at = [&](const ClusterReference& ref) -> std::span<const std::byte> {
        ObjectLookup clas =
            dir.lookup(memory, ref.clas_address, ObjectType::kTriangleCluster, false, where);
        if (clas.found()) return clas.bytes;
        if (findings &&
            std::find(reported.begin(), reported.end(), ref.reference_index) == reported.end()) {
            reported.push_back(ref.reference_index);
            findings->push_back({kRuleStaleClusterReference,
                                 "trace: cluster reference " + std::to_string(ref.reference_index) +
                                     ": " + clas.error,
                                 -1, ref.clas_address});
        }
        return {};
    };
    walk_bytes(blas.bytes, ray, mode, clas_at, visit);
}

// A visitor keeping the closest hit (the first with kRayFlagTerminateOnFirstHit or `first`).
struct ClosestVisitor {
    const Ray& ray;
    uint32_t ray_flags;
    bool first;
    TraversalMode mode;
    BottomLevelHit& best;
    template <class Clas>
    bool operator()(Clas clas, const ClusterReference& ref, double& tmax) {
        const Hit h = trace_clas(clas, clipped_ray(ray, best), ray_flags, mode);
        if (replaces(best, h, ref)) {
            best.hit = h;
            best.reference_index = ref.reference_index;
            best.clas_address = ref.clas_address;
            tmax = h.t;
            if (first || (ray_flags & kRayFlagTerminateOnFirstHit)) return false;
        }
        return true;
    }
};

}  // namespace

BottomLevelHit trace_bottom_level_closest(const MemoryImage& memory, uint64_t blas_address,
                                          const Ray& ray, uint32_t ray_flags,
                                          const ObjectDirectory* directory,
                                          std::vector<Finding>* findings, TraversalMode mode) {
    BottomLevelHit best;
    walk(memory, blas_address, ray, mode, directory, findings,
         ClosestVisitor{ray, ray_flags, false, mode, best});
    return best;
}

BottomLevelHit trace_bottom_level_bytes(
    std::span<const std::byte> blas,
    const std::function<std::span<const std::byte>(uint64_t clas_address)>& clas_at, const Ray& ray,
    uint32_t ray_flags, bool first_hit, TraversalMode mode) {
    BottomLevelHit best;
    walk_bytes(
        blas, ray, mode, [&](const ClusterReference& ref) { return clas_at(ref.clas_address); },
        ClosestVisitor{ray, ray_flags, first_hit, mode, best});
    return best;
}

BottomLevelHit trace_bottom_level_views(
    std::span<const std::byte> blas,
    const std::function<const ClasView*(uint64_t clas_address)>& clas_at, const Ray& ray,
    uint32_t ray_flags, bool first_hit, TraversalMode mode) {
    BottomLevelHit best;
    walk_bytes(
        blas, ray, mode, [&](const ClusterReference& ref) { return clas_at(ref.clas_address); },
        ClosestVisitor{ray, ray_flags, first_hit, mode, best});
    return best;
}

BottomLevelHit trace_bottom_level_bytes_exhaustive(
    std::span<const std::byte> blas,
    const std::function<std::span<const std::byte>(uint64_t clas_address)>& clas_at, const Ray& ray,
    uint32_t ray_flags, TraversalMode mode) {
    BottomLevelHit best;
    BottomLevelHeader h;
    std::memcpy(&h, blas.data(), sizeof h);
    for (uint32_t k = 0; k < h.reference_count; ++k) {
        ClusterReference ref;
        std::memcpy(&ref, blas.data() + h.references_offset + uint64_t(k) * sizeof ref, sizeof ref);
        const std::span<const std::byte> bytes = clas_at(ref.clas_address);
        const auto clas = bytes.empty() ? std::nullopt : open_clas(bytes);
        if (!clas) continue;
        const Hit hit = trace_closest_exhaustive(*clas, ray, ray_flags, mode);
        if (!replaces(best, hit, ref)) continue;
        best.hit = hit;
        best.reference_index = ref.reference_index;
        best.clas_address = ref.clas_address;
    }
    return best;
}

bool trace_bottom_level_any(const MemoryImage& memory, uint64_t blas_address, const Ray& ray,
                            uint32_t ray_flags, const ObjectDirectory* directory,
                            std::vector<Finding>* findings, TraversalMode mode) {
    bool any = false;
    walk(memory, blas_address, ray, mode, directory, findings,
         [&](std::span<const std::byte> clas, const ClusterReference&, double&) {
             any = trace_any(clas, ray, ray_flags, mode);
             return !any;
         });
    return any;
}

}  // namespace clastrace::engine
