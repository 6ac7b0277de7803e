// SPDX-License-Identifier: Apache-2.0
// BLAS -> CLAS traversal: the engine's conservative slab test (geometry/slab.h) per BVH
// node, then the CLAS traversal (traversal.h) per referenced cluster. Children are visited nearest
// first; a later hit replaces the best only when strictly closer, so ties resolve by node
// order.
#include "clastrace/engine/blas.h"

#include "geometry/slab.h"

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
    std::vector<uint32_t> stack{0};
    double tmax = ray.tmax;
    while (!stack.empty()) {
        uint32_t i = stack.back();
        stack.pop_back();
        BottomLevelNode n = node_at(i);
        double entry;
        if (!hit_box(rb, n, tmax, entry)) continue;
        if (n.count == 0) {
            BottomLevelNode l = node_at(n.first), r = node_at(n.first + 1);
            double el = 0, er = 0;
            bool hl = hit_box(rb, l, tmax, el), hr = hit_box(rb, r, tmax, er);
            if (hl && hr) {
                if (el <= er) {
                    stack.push_back(n.first + 1);
                    stack.push_back(n.first);
                } else {
                    stack.push_back(n.first);
                    stack.push_back(n.first + 1);
                }
            } else if (hl) {
                stack.push_back(n.first);
            } else if (hr) {
                stack.push_back(n.first + 1);
            }
            continue;
        }
        for (uint32_t k = 0; k < n.count; ++k) {
            ClusterReference ref;
            std::memcpy(&ref,
                        blas.data() + h.references_offset + uint64_t(n.first + k) * sizeof ref,
                        sizeof ref);
            std::span<const std::byte> clas = clas_at(ref);
            if (clas.empty()) continue;
            if (!visit(clas, ref, tmax)) return;
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
    bool operator()(std::span<const std::byte> clas, const ClusterReference& ref, double& tmax) {
        Ray r = ray;
        r.tmax = float(tmax);
        Hit h = trace_closest(clas, r, ray_flags, mode);
        if (h.hit && (!best.hit.hit || h.t < best.hit.t)) {
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
