// SPDX-License-Identifier: Apache-2.0
// A 0.01-thick slab inside a 1e-2-scaled instance (rotated, translated, and mirrored), traced
// in both traversal modes against the exact answer: the ray enters through the face nearer
// along it (front-facing: facing is decided in object space, mirrored or not) and leaves
// through the other (back-facing), at the t the exact double inverse of the float instance
// transform gives, within the hit's own float32 error bound. The slab is 1e-4 thick in world
// space: a traversal whose instance transform or box test rounds carelessly skips the near
// face (h100_nv_extremes caught such a ray in double mode before the float32 mode).
#include "nv_scene.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>

namespace clastrace::nvtest {
namespace {

constexpr float kHalf = 0.15f;    // the slab's half extent in x and y (object space)
constexpr float kFaceZ = 0.005f;  // its faces at z = +-kFaceZ

// Two faces only: primitives 0, 1 at +kFaceZ (normal +z), 2, 3 at -kFaceZ (normal -z),
// both wound so that cross(v1 - v0, v2 - v0) points out of the slab.
BlasSpec slab() {
    ts::TriangleMesh m;
    m.positions = {{-kHalf, -kHalf, kFaceZ}, {kHalf, -kHalf, kFaceZ},   {kHalf, kHalf, kFaceZ},
                   {-kHalf, kHalf, kFaceZ},  {-kHalf, -kHalf, -kFaceZ}, {kHalf, -kHalf, -kFaceZ},
                   {kHalf, kHalf, -kFaceZ},  {-kHalf, kHalf, -kFaceZ}};
    m.triangles = {{0, 1, 2}, {0, 2, 3}, {4, 6, 5}, {4, 7, 6}};
    BlasSpec s;
    s.geometries.push_back({m, {}, VK_GEOMETRY_OPAQUE_BIT_NV});
    return s;
}

// Rotation about (1, 2, 3) by 0.7 rad, times 1e-2, x column negated when mirrored, moved to
// (3.25, -1.5, 7).
InstanceSpec scaled_instance(bool mirrored) {
    double axis[3] = {1, 2, 3};
    const double len = std::sqrt(14.0);
    for (double& a : axis) a /= len;
    const double c = std::cos(0.7), s = std::sin(0.7), t = 1 - c;
    const double r[9] = {t * axis[0] * axis[0] + c,
                         t * axis[0] * axis[1] - s * axis[2],
                         t * axis[0] * axis[2] + s * axis[1],
                         t * axis[0] * axis[1] + s * axis[2],
                         t * axis[1] * axis[1] + c,
                         t * axis[1] * axis[2] - s * axis[0],
                         t * axis[0] * axis[2] - s * axis[1],
                         t * axis[1] * axis[2] + s * axis[0],
                         t * axis[2] * axis[2] + c};
    const float move[3] = {3.25f, -1.5f, 7.0f};
    InstanceSpec inst;
    for (int row = 0; row < 3; ++row) {
        for (int k = 0; k < 3; ++k)
            inst.transform[4 * row + k] =
                float(r[3 * row + k] * 1e-2 * (mirrored && k == 0 ? -1 : 1));
        inst.transform[4 * row + 3] = move[row];
    }
    return inst;
}

// The float 3x4 matrix's linear part inverted exactly enough (double, one rounding per step).
struct ExactInverse {
    double m[9], t[3];
    explicit ExactInverse(const float* f) {
        const double a = f[0], b = f[1], c = f[2], d = f[4], e = f[5], g = f[6], h = f[8], i = f[9],
                     k = f[10];
        const double det = a * (e * k - g * i) - b * (d * k - g * h) + c * (d * i - e * h);
        const double inv[9] = {(e * k - g * i) / det, (c * i - b * k) / det, (b * g - c * e) / det,
                               (g * h - d * k) / det, (a * k - c * h) / det, (c * d - a * g) / det,
                               (d * i - e * h) / det, (b * h - a * i) / det, (a * e - b * d) / det};
        for (int x = 0; x < 9; ++x) m[x] = inv[x];
        for (int x = 0; x < 3; ++x) t[x] = f[4 * x + 3];
    }
    void point(const float p[3], double out[3]) const {
        const double q[3] = {p[0] - t[0], p[1] - t[1], p[2] - t[2]};
        vector(q, out);
    }
    void vector(const double v[3], double out[3]) const {
        for (int r = 0; r < 3; ++r)
            out[r] = m[3 * r] * v[0] + m[3 * r + 1] * v[1] + m[3 * r + 2] * v[2];
    }
};

struct Expected {
    double t_near, t_far;
    bool near_is_top;
};

// The exact crossing of the float ray with both face planes, when both lie well inside the
// faces (0.9 of the half extent: the diagonal inside a face is shared by its two triangles,
// either may answer).
bool exact_crossing(const ExactInverse& inv, const eng::Ray& ray, Expected* out) {
    double o[3], d[3];
    const double wd[3] = {ray.direction[0], ray.direction[1], ray.direction[2]};
    inv.point(ray.origin, o);
    inv.vector(wd, d);
    const double t_top = (double(kFaceZ) - o[2]) / d[2], t_bottom = (-double(kFaceZ) - o[2]) / d[2];
    for (double t : {t_top, t_bottom})
        for (int k = 0; k < 2; ++k)
            if (std::fabs(o[k] + t * d[k]) > 0.9 * kHalf) return false;
    out->near_is_top = t_top < t_bottom;
    out->t_near = std::min(t_top, t_bottom);
    out->t_far = std::max(t_top, t_bottom);
    return true;
}

// A world ray aimed at a random point of the slab's middle plane from 10 units away, along a
// random object-space direction within 60 degrees of the slab's normal.
eng::Ray aimed_ray(const InstanceSpec& inst, std::mt19937_64& rng) {
    std::uniform_real_distribution<float> u(-1.0f, 1.0f);
    const float p[3] = {u(rng) * 0.8f * kHalf, u(rng) * 0.8f * kHalf, 0.0f};
    const float dz = u(rng) < 0 ? -1.0f : 1.0f;
    const float d_obj[3] = {u(rng) * 0.5f, u(rng) * 0.5f, dz};
    double wp[3], wd[3], len = 0;
    for (int r = 0; r < 3; ++r) {
        const float* row = inst.transform + 4 * r;
        wp[r] = row[0] * p[0] + row[1] * p[1] + row[2] * p[2] + row[3];
        wd[r] = row[0] * d_obj[0] + row[1] * d_obj[1] + row[2] * d_obj[2];
        len += wd[r] * wd[r];
    }
    eng::Ray ray{};
    for (int r = 0; r < 3; ++r) {
        ray.direction[r] = float(wd[r] / std::sqrt(len));
        ray.origin[r] = float(wp[r] - 10.0 * ray.direction[r]);
    }
    ray.tmin = 0.0f;
    ray.tmax = 1e30f;
    return ray;
}

void expect_face(const eng::NvHit& hit, double t_exact, bool top, bool front, const char* what,
                 int ray) {
    ASSERT_TRUE(hit.hit) << what << " ray " << ray;
    EXPECT_EQ(hit.primitive_index / 2, top ? 0u : 1u) << what << " ray " << ray;
    EXPECT_EQ(hit.hit_kind, front ? eng::kHitKindFrontFacing : eng::kHitKindBackFacing)
        << what << " ray " << ray;
    EXPECT_LE(std::fabs(double(hit.t) - t_exact), double(hit.t_error))
        << what << " ray " << ray << " t " << hit.t << " exact " << t_exact;
}

void trace_slab(bool mirrored, eng::TraversalMode mode) {
    const InstanceSpec inst = scaled_instance(mirrored);
    auto built = build_scene({slab()}, {inst});
    ASSERT_TRUE(built->findings.empty()) << built->findings.front();
    std::string error;
    auto scene = eng::NvScene::open(built->world.memory, built->tlas.address, nullptr, &error);
    ASSERT_TRUE(scene) << error;
    const ExactInverse inv(inst.transform);
    const std::string what = std::string(mirrored ? "mirrored " : "") + "1e-2 instance, " +
                             eng::traversal_mode_name(mode);
    std::mt19937_64 rng(mirrored ? 17 : 16);
    int checked = 0;
    for (int i = 0; i < 3000; ++i) {
        const eng::Ray ray = aimed_ray(inst, rng);
        Expected x;
        if (!exact_crossing(inv, ray, &x)) continue;
        ++checked;
        const eng::NvHit entry = scene->closest(ray, 0, 0xFF, mode);
        // The bound must tell the faces apart, or the test proves nothing.
        ASSERT_LT(2.0 * entry.t_error, x.t_far - x.t_near) << what << " ray " << i;
        expect_face(entry, x.t_near, x.near_is_top, true, what.c_str(), i);
        expect_face(scene->closest(ray, eng::kRayFlagCullBackFacingTriangles, 0xFF, mode), x.t_near,
                    x.near_is_top, true, (what + ", cull back").c_str(), i);
        expect_face(scene->closest(ray, eng::kRayFlagCullFrontFacingTriangles, 0xFF, mode), x.t_far,
                    !x.near_is_top, false, (what + ", cull front").c_str(), i);
        if (::testing::Test::HasFailure()) return;
    }
    EXPECT_GT(checked, 2000) << what;
}

TEST(NvThinSlab, ScaledInstanceDouble) { trace_slab(false, eng::TraversalMode::kDouble); }
TEST(NvThinSlab, ScaledInstanceFloat32) { trace_slab(false, eng::TraversalMode::kFloat32); }
TEST(NvThinSlab, MirroredScaledInstanceDouble) { trace_slab(true, eng::TraversalMode::kDouble); }
TEST(NvThinSlab, MirroredScaledInstanceFloat32) { trace_slab(true, eng::TraversalMode::kFloat32); }

}  // namespace
}  // namespace clastrace::nvtest
