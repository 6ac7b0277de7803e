// SPDX-License-Identifier: Apache-2.0
#include "nv_scene.h"

#include <clastrace/testsupport/rays.h>

#include <gtest/gtest.h>

#include <algorithm>
#include <cstdio>
#include <cmath>
#include <cstring>
#include <random>
#include <sstream>
#include <stdexcept>

namespace clastrace::nvtest {

uint64_t NvWorld::alloc(uint64_t size, const std::string& label) {
    const uint64_t base = next;
    memory.add_region(base, std::max<uint64_t>(size, 1), 0, label);
    next = (base + std::max<uint64_t>(size, 1) + 4096 + 255) / 256 * 256;
    return base;
}

uint64_t NvWorld::put(const void* data, uint64_t size, const std::string& label) {
    const uint64_t a = alloc(size, label);
    if (size) std::memcpy(memory.write_bytes(a, size, {label.c_str(), -1}).data(), data, size);
    return a;
}

eng::NvObjectBinding NvWorld::make_object(const eng::NvObjectInfo& info, const std::string& label) {
    eng::NvObjectBinding b;
    const uint64_t size = eng::nv_memory_requirements(info).object;
    b.address = alloc(size, label);
    b.handle = b.address;
    b.size = size;
    b.bound = true;
    b.created = info;
    return b;
}

uint64_t NvWorld::scratch(uint64_t size) { return alloc(size, "scratch"); }

eng::NvObjectInfo NvWorld::blas_info(const BlasSpec& spec,
                                     VkBuildAccelerationStructureFlagsNV flags) {
    eng::NvObjectInfo info;
    info.type = VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_NV;
    info.flags = flags;
    for (const GeometrySpec& g : spec.geometries) {
        eng::NvGeometry geo;
        geo.flags = g.flags;
        if (spec.aabbs) {
            geo.type = VK_GEOMETRY_TYPE_AABBS_NV;
            geo.aabbs.address = put(g.boxes.data(), g.boxes.size() * 24, "aabbs");
            geo.aabbs.count = uint32_t(g.boxes.size());
            geo.aabbs.stride = 24;
        } else {
            geo.type = VK_GEOMETRY_TYPE_TRIANGLES_NV;
            geo.triangles.vertex_address =
                put(g.mesh.positions.data(), g.mesh.positions.size() * 12, "vertices");
            geo.triangles.vertex_count = uint32_t(g.mesh.positions.size());
            geo.triangles.vertex_stride = 12;
            geo.triangles.vertex_format = VK_FORMAT_R32G32B32_SFLOAT;
            geo.triangles.index_address =
                put(g.mesh.triangles.data(), g.mesh.triangles.size() * 12, "indices");
            geo.triangles.index_count = uint32_t(g.mesh.triangles.size() * 3);
            geo.triangles.index_type = VK_INDEX_TYPE_UINT32;
        }
        info.geometries.push_back(geo);
    }
    return info;
}

std::vector<uint8_t> NvWorld::instance_bytes(const std::vector<InstanceSpec>& instances,
                                             const std::vector<uint64_t>& handles) const {
    std::vector<uint8_t> out(instances.size() * 64);
    for (size_t i = 0; i < instances.size(); ++i) {
        const InstanceSpec& s = instances[i];
        uint8_t* p = out.data() + 64 * i;
        std::memcpy(p, s.transform, 48);
        const uint32_t a = (s.custom_index & 0xFFFFFF) | (s.mask << 24),
                       b = (s.sbt_offset & 0xFFFFFF) | (s.flags << 24);
        const uint64_t ref = s.blas < 0 ? 0 : handles[size_t(s.blas)];
        std::memcpy(p + 48, &a, 4);
        std::memcpy(p + 52, &b, 4);
        std::memcpy(p + 56, &ref, 8);
    }
    return out;
}

eng::ExecutionRecord NvWorld::build(const eng::NvObjectInfo& info, eng::NvObjectBinding& dst,
                                    uint64_t instance_address, bool update,
                                    const eng::NvObjectBinding* src,
                                    const eng::NvBuildOptions& options) {
    eng::NvBuildCommand cmd;
    cmd.info = info;
    cmd.instance_address = instance_address;
    cmd.update = update;
    cmd.dst = dst;
    if (src) cmd.src = *src;
    const eng::NvMemoryRequirements need = eng::nv_memory_requirements(info);
    // Hostile counts ask for huge scratch: the test world gives at most 16 MiB (the engine
    // then reports the scratch rule, which is what such a command breaks).
    const uint64_t s =
        std::min<uint64_t>(update ? need.update_scratch : need.build_scratch, 16ull << 20);
    cmd.scratch_address = scratch(s);
    cmd.scratch_available = s;
    eng::ExecutionRecord r = eng::execute_nv_build(cmd, memory, options);
    if (r.ops[0].executed) {
        dst.built = true;
        dst.built_flags = info.flags;
    }
    return r;
}

std::unique_ptr<BuiltScene> build_scene(const std::vector<BlasSpec>& blas,
                                        const std::vector<InstanceSpec>& instances,
                                        VkBuildAccelerationStructureFlagsNV flags) {
    auto s = std::make_unique<BuiltScene>();
    std::vector<uint64_t> handles;
    auto note = [&](const eng::ExecutionRecord& r) {
        for (const auto& f : r.findings) s->findings.push_back(f.rule + ": " + f.message);
    };
    for (const BlasSpec& b : blas) {
        eng::NvObjectInfo info = s->world.blas_info(b, flags);
        eng::NvObjectBinding obj = s->world.make_object(info, "blas");
        note(s->world.build(info, obj));
        handles.push_back(obj.handle);
        s->blas.push_back(obj);
    }
    eng::NvObjectInfo top;
    top.type = VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_NV;
    top.flags = flags;
    top.instance_count = uint32_t(instances.size());
    std::vector<uint8_t> bytes = s->world.instance_bytes(instances, handles);
    s->instance_address = s->world.put(bytes.data(), bytes.size(), "instances");
    s->tlas = s->world.make_object(top, "tlas");
    note(s->world.build(top, s->tlas, s->instance_address));
    return s;
}

// ---------------------------------------------------------------------------- Embree

struct EmbreeNvScene::Geometry {
    bool aabbs = false;
    uint32_t flags = 0;
    std::vector<ts::Float3> positions;
    std::vector<ts::Triangle> triangles;
    std::vector<std::array<float, 6>> boxes;
};

namespace {

struct RayContext {
    RTCIntersectContext base;  // first: Embree passes this address to the callbacks
    const std::vector<EmbreeNvScene::Instance>* instances;
    uint32_t flags;
    uint32_t cull_mask;
    double wdir[3];
};

// Vulkan's mask, opacity and facing rules for one candidate; the hit kind on accept.
bool accept(const RayContext& c, uint32_t inst_id, const EmbreeNvScene::Geometry& g, uint32_t prim,
            uint32_t* kind) {
    const EmbreeNvScene::Instance& in = (*c.instances)[inst_id];
    if (!(in.spec.mask & c.cull_mask & 0xFFu)) return false;
    bool opaque = g.flags & VK_GEOMETRY_OPAQUE_BIT_NV;
    if (in.spec.flags & VK_GEOMETRY_INSTANCE_FORCE_OPAQUE_BIT_NV) opaque = true;
    if (in.spec.flags & VK_GEOMETRY_INSTANCE_FORCE_NO_OPAQUE_BIT_NV) opaque = false;
    if (c.flags & eng::kRayFlagOpaque) opaque = true;
    if (c.flags & eng::kRayFlagNoOpaque) opaque = false;
    if ((c.flags & eng::kRayFlagCullOpaque) && opaque) return false;
    if ((c.flags & eng::kRayFlagCullNoOpaque) && !opaque) return false;
    *kind = 0;
    if (g.aabbs) return true;
    double d[3];
    for (int r = 0; r < 3; ++r)
        d[r] = in.inverse[4 * r] * c.wdir[0] + in.inverse[4 * r + 1] * c.wdir[1] +
               in.inverse[4 * r + 2] * c.wdir[2];
    const ts::Triangle& t = g.triangles[prim];
    const ts::Float3 &a = g.positions[t[0]], &b = g.positions[t[1]], &cc = g.positions[t[2]];
    const double e1[3] = {double(b[0]) - a[0], double(b[1]) - a[1], double(b[2]) - a[2]};
    const double e2[3] = {double(cc[0]) - a[0], double(cc[1]) - a[1], double(cc[2]) - a[2]};
    const double n[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
                         e1[0] * e2[1] - e1[1] * e2[0]};
    bool front = d[0] * n[0] + d[1] * n[1] + d[2] * n[2] < 0.0;
    if (in.spec.flags & VK_GEOMETRY_INSTANCE_TRIANGLE_FRONT_COUNTERCLOCKWISE_BIT_NV) front = !front;
    if (!(in.spec.flags & VK_GEOMETRY_INSTANCE_TRIANGLE_CULL_DISABLE_BIT_NV)) {
        if ((c.flags & eng::kRayFlagCullBackFacingTriangles) && !front) return false;
        if ((c.flags & eng::kRayFlagCullFrontFacingTriangles) && front) return false;
    }
    *kind = front ? eng::kHitKindFrontFacing : eng::kHitKindBackFacing;
    return true;
}

void triangle_filter(const RTCFilterFunctionNArguments* args) {
    const auto& c = *reinterpret_cast<const RayContext*>(args->context);
    const auto* hit = reinterpret_cast<const RTCHit*>(args->hit);
    const auto& g = *static_cast<const EmbreeNvScene::Geometry*>(args->geometryUserPtr);
    uint32_t kind;
    if (!accept(c, hit->instID[0], g, hit->primID, &kind)) args->valid[0] = 0;
}

double slab_entry(const float o[3], const float d[3], const float lo[3], const float hi[3],
                  double tn, double tf) {
    for (int a = 0; a < 3; ++a) {
        if (d[a] == 0.0f) {
            if (!(o[a] >= lo[a] && o[a] <= hi[a])) return -1;
            continue;
        }
        double t0 = (double(lo[a]) - o[a]) / d[a], t1 = (double(hi[a]) - o[a]) / d[a];
        if (t0 > t1) std::swap(t0, t1);
        tn = std::max(tn, t0);
        tf = std::min(tf, t1);
    }
    return tn <= tf ? tn : -1;
}

void box_bounds(const RTCBoundsFunctionArguments* args) {
    const auto& g = *static_cast<const EmbreeNvScene::Geometry*>(args->geometryUserPtr);
    const auto& b = g.boxes[args->primID];
    *args->bounds_o = RTCBounds{b[0], b[1], b[2], 0, b[3], b[4], b[5], 0};
}

void box_intersect(const RTCIntersectFunctionNArguments* args) {
    if (!args->valid[0]) return;
    const auto& c = *reinterpret_cast<const RayContext*>(args->context);
    const auto& g = *static_cast<const EmbreeNvScene::Geometry*>(args->geometryUserPtr);
    auto* rh = reinterpret_cast<RTCRayHit*>(args->rayhit);
    const auto& b = g.boxes[args->primID];
    const float o[3] = {rh->ray.org_x, rh->ray.org_y, rh->ray.org_z},
                d[3] = {rh->ray.dir_x, rh->ray.dir_y, rh->ray.dir_z};
    const double t = slab_entry(o, d, b.data(), b.data() + 3, rh->ray.tnear, rh->ray.tfar);
    if (t < 0 || std::isnan(t) || b[0] > b[3]) return;
    uint32_t kind;
    if (!accept(c, args->context->instID[0], g, args->primID, &kind)) return;
    rh->ray.tfar = float(t);
    rh->hit.u = rh->hit.v = 0;
    rh->hit.Ng_x = 0;
    rh->hit.Ng_y = 0;
    rh->hit.Ng_z = 1;
    rh->hit.primID = args->primID;
    rh->hit.geomID = args->geomID;
    rh->hit.instID[0] = args->context->instID[0];
}

void box_occluded(const RTCOccludedFunctionNArguments* args) {
    if (!args->valid[0]) return;
    const auto& c = *reinterpret_cast<const RayContext*>(args->context);
    const auto& g = *static_cast<const EmbreeNvScene::Geometry*>(args->geometryUserPtr);
    auto* ray = reinterpret_cast<RTCRay*>(args->ray);
    const auto& b = g.boxes[args->primID];
    const float o[3] = {ray->org_x, ray->org_y, ray->org_z},
                d[3] = {ray->dir_x, ray->dir_y, ray->dir_z};
    const double t = slab_entry(o, d, b.data(), b.data() + 3, ray->tnear, ray->tfar);
    if (t < 0 || std::isnan(t) || b[0] > b[3]) return;
    uint32_t kind;
    if (!accept(c, args->context->instID[0], g, args->primID, &kind)) return;
    ray->tfar = -std::numeric_limits<float>::infinity();
}

bool invert(const float m[12], double out[12]) {
    const double a = m[0], b = m[1], c = m[2], d = m[4], e = m[5], f = m[6], g = m[8], h = m[9],
                 i = m[10];
    const double det = a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g);
    if (det == 0.0) return false;
    const double r[9] = {(e * i - f * h) / det, (c * h - b * i) / det, (b * f - c * e) / det,
                         (f * g - d * i) / det, (a * i - c * g) / det, (c * d - a * f) / det,
                         (d * h - e * g) / det, (b * g - a * h) / det, (a * e - b * d) / det};
    for (int row = 0; row < 3; ++row) {
        for (int k = 0; k < 3; ++k) out[4 * row + k] = r[3 * row + k];
        out[4 * row + 3] = -(r[3 * row] * m[3] + r[3 * row + 1] * m[7] + r[3 * row + 2] * m[11]);
    }
    return true;
}

RayContext context_for(const std::vector<EmbreeNvScene::Instance>& instances, const eng::Ray& ray,
                       uint32_t flags, uint32_t cull_mask) {
    RayContext c;
    rtcInitIntersectContext(&c.base);
    c.instances = &instances;
    c.flags = flags;
    c.cull_mask = cull_mask;
    for (int a = 0; a < 3; ++a) c.wdir[a] = ray.direction[a];
    return c;
}

RTCRay embree_ray(const eng::Ray& r) {
    RTCRay ray{};
    ray.org_x = r.origin[0];
    ray.org_y = r.origin[1];
    ray.org_z = r.origin[2];
    ray.dir_x = r.direction[0];
    ray.dir_y = r.direction[1];
    ray.dir_z = r.direction[2];
    ray.tnear = r.tmin;
    ray.tfar = r.tmax;
    ray.mask = ~0u;
    return ray;
}

}  // namespace

EmbreeNvScene::EmbreeNvScene(const std::vector<BlasSpec>& blas,
                             const std::vector<InstanceSpec>& instances) {
    device_ = rtcNewDevice("threads=1");
    if (!device_) throw std::runtime_error("rtcNewDevice failed");
    for (const BlasSpec& b : blas) {
        RTCScene scene = rtcNewScene(device_);
        rtcSetSceneFlags(scene, RTC_SCENE_FLAG_ROBUST);
        for (size_t gi = 0; gi < b.geometries.size(); ++gi) {
            const GeometrySpec& spec = b.geometries[gi];
            auto geo = std::make_unique<Geometry>();
            geo->aabbs = b.aabbs;
            geo->flags = spec.flags;
            RTCGeometry g;
            if (b.aabbs) {
                geo->boxes = spec.boxes;
                g = rtcNewGeometry(device_, RTC_GEOMETRY_TYPE_USER);
                rtcSetGeometryUserPrimitiveCount(g, unsigned(geo->boxes.size()));
                rtcSetGeometryBoundsFunction(g, box_bounds, nullptr);
                rtcSetGeometryIntersectFunction(g, box_intersect);
                rtcSetGeometryOccludedFunction(g, box_occluded);
            } else {
                geo->positions = spec.mesh.positions;
                geo->triangles = spec.mesh.triangles;
                g = rtcNewGeometry(device_, RTC_GEOMETRY_TYPE_TRIANGLE);
                auto* v = static_cast<float*>(rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0,
                                                                      RTC_FORMAT_FLOAT3, 12,
                                                                      geo->positions.size()));
                std::memcpy(v, geo->positions.data(), geo->positions.size() * 12);
                auto* ix = static_cast<uint32_t*>(rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX,
                                                                          0, RTC_FORMAT_UINT3, 12,
                                                                          geo->triangles.size()));
                std::memcpy(ix, geo->triangles.data(), geo->triangles.size() * 12);
                rtcSetGeometryIntersectFilterFunction(g, triangle_filter);
                rtcSetGeometryOccludedFilterFunction(g, triangle_filter);
            }
            rtcSetGeometryUserData(g, geo.get());
            rtcCommitGeometry(g);
            rtcAttachGeometryByID(scene, g, unsigned(gi));
            rtcReleaseGeometry(g);
            geometries_.push_back(std::move(geo));
        }
        rtcCommitScene(scene);
        blas_.push_back(scene);
    }
    top_ = rtcNewScene(device_);
    rtcSetSceneFlags(top_, RTC_SCENE_FLAG_ROBUST);
    for (size_t i = 0; i < instances.size(); ++i) {
        Instance in{instances[i], {}};
        const bool ok = invert(instances[i].transform, in.inverse);
        instances_.push_back(in);
        if (instances[i].blas < 0 || !ok) continue;
        RTCGeometry g = rtcNewGeometry(device_, RTC_GEOMETRY_TYPE_INSTANCE);
        rtcSetGeometryInstancedScene(g, blas_[size_t(instances[i].blas)]);
        rtcSetGeometryTransform(g, 0, RTC_FORMAT_FLOAT3X4_ROW_MAJOR, instances[i].transform);
        rtcCommitGeometry(g);
        rtcAttachGeometryByID(top_, g, unsigned(i));
        rtcReleaseGeometry(g);
    }
    rtcCommitScene(top_);
}

EmbreeNvScene::~EmbreeNvScene() {
    if (top_) rtcReleaseScene(top_);
    for (RTCScene s : blas_) rtcReleaseScene(s);
    if (device_) rtcReleaseDevice(device_);
}

RefHit EmbreeNvScene::closest(const eng::Ray& ray, uint32_t flags, uint32_t cull_mask) const {
    RayContext c = context_for(instances_, ray, flags, cull_mask);
    RTCRayHit rh{};
    rh.ray = embree_ray(ray);
    rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
    rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
    rtcIntersect1(top_, &c.base, &rh);
    RefHit out;
    if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) return out;
    out.hit = true;
    out.t = rh.ray.tfar;
    out.instance = rh.hit.instID[0];
    out.custom_index = instances_[out.instance].spec.custom_index & 0xFFFFFF;
    out.geometry = rh.hit.geomID;
    out.primitive = rh.hit.primID;
    out.u = rh.hit.u;
    out.v = rh.hit.v;
    const Geometry* g = static_cast<const Geometry*>(rtcGetGeometryUserData(
        rtcGetGeometry(blas_[size_t(instances_[out.instance].spec.blas)], out.geometry)));
    accept(c, out.instance, *g, out.primitive, &out.hit_kind);
    return out;
}

bool EmbreeNvScene::any(const eng::Ray& ray, uint32_t flags, uint32_t cull_mask) const {
    RayContext c = context_for(instances_, ray, flags, cull_mask);
    RTCRay r = embree_ray(ray);
    rtcOccluded1(top_, &c.base, &r);
    return r.tfar < 0 && std::isinf(r.tfar);
}

// ---------------------------------------------------------------------------- agreement

std::string Agreement::summary() const {
    std::ostringstream s;
    s << "rays " << rays << ": agree-miss " << agree_miss << ", agree-hit " << agree_hit << ", tie "
      << tie << ", edge " << edge << ", disagree " << disagree << "; any-hit agree " << any_agree
      << ", disagree " << any_disagree << "; max relative t error " << max_rel_t;
    return s.str();
}

namespace {
bool near_edge(float u, float v, uint32_t kind) {
    if (kind != eng::kHitKindFrontFacing && kind != eng::kHitKindBackFacing) return false;
    return std::min({u, v, 1.0f - u - v}) < 1e-5f;
}
}  // namespace

void classify(Agreement& a, const eng::NvHit& e, const RefHit& r, double tol,
              const std::string& what) {
    ++a.rays;
    auto example = [&](const char* kind) {
        if (a.examples.size() >= 8) return;
        std::ostringstream s;
        s << kind << " " << what << ": engine " << (e.hit ? "hit" : "miss") << " t=" << e.t
          << " inst " << e.instance_index << " geom " << e.geometry_index << " prim "
          << e.primitive_index << " kind " << e.hit_kind << " uv " << e.u << "," << e.v
          << " | embree " << (r.hit ? "hit" : "miss") << " t=" << r.t << " inst " << r.instance
          << " geom " << r.geometry << " prim " << r.primitive << " kind " << r.hit_kind << " uv "
          << r.u << "," << r.v;
        a.examples.push_back(s.str());
    };
    if (!e.hit && !r.hit) {
        ++a.agree_miss;
        return;
    }
    if (e.hit && r.hit) {
        const double rel = std::fabs(double(e.t) - r.t) / std::max(std::fabs(double(r.t)), 1e-30);
        const bool same = e.instance_index == r.instance && e.geometry_index == r.geometry &&
                          e.primitive_index == r.primitive;
        if (same && rel <= tol) {
            a.max_rel_t = std::max(a.max_rel_t, rel);
            if (e.hit_kind != r.hit_kind || e.instance_custom_index != r.custom_index ||
                (e.hit_kind != 0 &&
                 (std::fabs(e.u - r.u) > 1e-3f || std::fabs(e.v - r.v) > 1e-3f))) {
                ++a.disagree;
                example("attributes");
                return;
            }
            ++a.agree_hit;
            return;
        }
        if (rel <= tol) {
            ++a.tie;
            return;
        }
    }
    if ((e.hit && near_edge(e.u, e.v, e.hit_kind)) || (r.hit && near_edge(r.u, r.v, r.hit_kind))) {
        ++a.edge;
        return;
    }
    ++a.disagree;
    example("disagree");
}

// ---------------------------------------------------------------------------- random scenes

std::vector<InstanceSpec> random_instances(size_t count, int blas_count, float extent,
                                           uint64_t seed) {
    std::mt19937_64 rng(seed);
    std::uniform_real_distribution<float> u(-1.0f, 1.0f);
    std::uniform_real_distribution<float> scale(0.5f, 2.0f);
    std::vector<InstanceSpec> out(count);
    for (size_t i = 0; i < count; ++i) {
        InstanceSpec& s = out[i];
        float axis[3] = {u(rng), u(rng), u(rng)};
        const float len =
            std::sqrt(axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2]) + 1e-6f;
        for (float& x : axis) x /= len;
        const float angle = u(rng) * 3.14159265f, c = std::cos(angle), sn = std::sin(angle),
                    t = 1 - c;
        const float R[9] = {t * axis[0] * axis[0] + c,
                            t * axis[0] * axis[1] - sn * axis[2],
                            t * axis[0] * axis[2] + sn * axis[1],
                            t * axis[0] * axis[1] + sn * axis[2],
                            t * axis[1] * axis[1] + c,
                            t * axis[1] * axis[2] - sn * axis[0],
                            t * axis[0] * axis[2] - sn * axis[1],
                            t * axis[1] * axis[2] + sn * axis[0],
                            t * axis[2] * axis[2] + c};
        float S[3] = {scale(rng), scale(rng), scale(rng)};
        if (rng() % 5 == 0)
            S[rng() % 3] *= -1.0f;  // mirrored instance: facing stays in object space
        for (int r = 0; r < 3; ++r) {
            for (int k = 0; k < 3; ++k) s.transform[4 * r + k] = R[3 * r + k] * S[k];
            s.transform[4 * r + 3] = u(rng) * extent;
        }
        s.custom_index = uint32_t(rng()) & 0xFFFFFF;
        s.mask = (rng() % 4 == 0) ? uint32_t(rng() & 0xFF) : 0xFFu;
        s.sbt_offset = uint32_t(rng()) & 0xFFFFFF;
        s.flags = 0;
        if (rng() % 4 == 0) s.flags |= VK_GEOMETRY_INSTANCE_TRIANGLE_CULL_DISABLE_BIT_NV;
        if (rng() % 4 == 0) s.flags |= VK_GEOMETRY_INSTANCE_TRIANGLE_FRONT_COUNTERCLOCKWISE_BIT_NV;
        const uint64_t o = rng() % 6;
        if (o == 0) s.flags |= VK_GEOMETRY_INSTANCE_FORCE_OPAQUE_BIT_NV;
        if (o == 1) s.flags |= VK_GEOMETRY_INSTANCE_FORCE_NO_OPAQUE_BIT_NV;
        s.blas = int(rng() % uint64_t(blas_count));
    }
    return out;
}

std::vector<std::array<float, 6>> random_boxes(size_t count, uint64_t seed) {
    std::mt19937_64 rng(seed);
    std::uniform_real_distribution<float> u(-1.0f, 1.0f), e(0.01f, 0.2f);
    std::vector<std::array<float, 6>> out(count);
    for (auto& b : out) {
        for (int a = 0; a < 3; ++a) {
            b[a] = u(rng);
            b[3 + a] = b[a] + e(rng);
        }
    }
    return out;
}

Agreement compare_with_embree(const eng::NvScene& scene, const EmbreeNvScene& embree,
                              size_t ray_count, float extent, uint64_t seed,
                              std::span<const uint32_t> flag_sets, float ray_scale) {
    ts::Bounds box;
    box.extend({-extent, -extent, -extent});
    box.extend({extent, extent, extent});
    const auto rays = ts::random_rays(box, ray_count, seed);
    std::mt19937_64 rng(seed);
    Agreement a;
    const float s = ray_scale;
    for (size_t i = 0; i < rays.size(); ++i) {
        const eng::Ray r{{rays[i].origin[0] * s, rays[i].origin[1] * s, rays[i].origin[2] * s},
                         rays[i].tmin * s,
                         {rays[i].direction[0], rays[i].direction[1], rays[i].direction[2]},
                         rays[i].tmax * s};
        const uint32_t flags = flag_sets[i % flag_sets.size()];
        const uint32_t mask = i % 3 == 0 ? uint32_t(rng() & 0xFF) : 0xFFu;
        classify(a, scene.closest(r, flags, mask), embree.closest(r, flags, mask), 1e-5,
                 "ray " + std::to_string(i) + " flags " + std::to_string(flags) + " mask " +
                     std::to_string(mask));
        if (i % 4 == 0)
            (scene.any(r, flags, mask) == embree.any(r, flags, mask) ? a.any_agree
                                                                     : a.any_disagree)++;
    }
    return a;
}

void expect_agreement(const Agreement& a, const std::string& what, AgreementFloor floor) {
    for (const auto& e : a.examples) ADD_FAILURE() << what << ": " << e;
    std::printf("[ embree agreement ] %s: %s\n", what.c_str(), a.summary().c_str());
    EXPECT_EQ(a.disagree, 0u) << what << ": " << a.summary();
    EXPECT_EQ(a.any_disagree, 0u) << what << ": " << a.summary();
    EXPECT_LT(a.tie + a.edge, a.rays / 200 + 1) << what << ": " << a.summary();
    if (floor.hit_divisor) {
        EXPECT_GT(a.agree_hit, a.rays / floor.hit_divisor) << what << ": " << a.summary();
    }
    if (floor.miss_divisor) {
        EXPECT_GT(a.agree_miss, a.rays / floor.miss_divisor) << what << ": " << a.summary();
    }
}

}  // namespace clastrace::nvtest
