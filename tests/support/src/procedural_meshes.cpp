// SPDX-License-Identifier: Apache-2.0
// Procedural meshes: closed shapes whose edges are shared by index (so a watertight traversal
// must not leak through them, whatever truncation does to the shared positions), a terrain and
// random soups.
#include "clastrace/testsupport/mesh.h"

#include <algorithm>
#include <bit>
#include <cmath>
#include <map>
#include <random>

namespace clastrace::testsupport {

TriangleMesh make_icosphere(int subdivisions, float radius) {
    TriangleMesh mesh;
    mesh.name = "icosphere" + std::to_string(subdivisions);
    const float t = (1.0f + std::sqrt(5.0f)) / 2.0f;
    std::vector<std::array<double, 3>> p = {{-1, t, 0}, {1, t, 0}, {-1, -t, 0}, {1, -t, 0},
                                            {0, -1, t}, {0, 1, t}, {0, -1, -t}, {0, 1, -t},
                                            {t, 0, -1}, {t, 0, 1}, {-t, 0, -1}, {-t, 0, 1}};
    std::vector<Triangle> tris = {{0, 11, 5}, {0, 5, 1},  {0, 1, 7},   {0, 7, 10}, {0, 10, 11},
                                  {1, 5, 9},  {5, 11, 4}, {11, 10, 2}, {10, 7, 6}, {7, 1, 8},
                                  {3, 9, 4},  {3, 4, 2},  {3, 2, 6},   {3, 6, 8},  {3, 8, 9},
                                  {4, 9, 5},  {2, 4, 11}, {6, 2, 10},  {8, 6, 7},  {9, 8, 1}};
    auto normalize = [](std::array<double, 3> v) {
        const double l = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
        return std::array<double, 3>{v[0] / l, v[1] / l, v[2] / l};
    };
    for (auto& v : p) v = normalize(v);
    for (int s = 0; s < subdivisions; ++s) {
        std::map<std::pair<uint32_t, uint32_t>, uint32_t> midpoint;
        auto mid = [&](uint32_t a, uint32_t b) {
            const std::pair<uint32_t, uint32_t> key = std::minmax(a, b);
            auto it = midpoint.find(key);
            if (it != midpoint.end()) return it->second;
            p.push_back(normalize(
                {(p[a][0] + p[b][0]) / 2, (p[a][1] + p[b][1]) / 2, (p[a][2] + p[b][2]) / 2}));
            const uint32_t idx = uint32_t(p.size() - 1);
            midpoint.emplace(key, idx);
            return idx;
        };
        std::vector<Triangle> next;
        for (const Triangle& tri : tris) {
            const uint32_t a = mid(tri[0], tri[1]), b = mid(tri[1], tri[2]),
                           c = mid(tri[2], tri[0]);
            next.push_back({tri[0], a, c});
            next.push_back({tri[1], b, a});
            next.push_back({tri[2], c, b});
            next.push_back({a, b, c});
        }
        tris.swap(next);
    }
    for (auto& v : p)
        mesh.positions.push_back(
            {float(v[0] * radius), float(v[1] * radius), float(v[2] * radius)});
    mesh.triangles = std::move(tris);
    return mesh;
}

TriangleMesh make_torus(int major_segments, int minor_segments, float major_radius,
                        float minor_radius) {
    TriangleMesh mesh;
    mesh.name = "torus" + std::to_string(major_segments) + "x" + std::to_string(minor_segments);
    const double two_pi = 6.283185307179586;
    for (int i = 0; i < major_segments; ++i) {
        const double u = two_pi * i / major_segments;
        for (int j = 0; j < minor_segments; ++j) {
            const double v = two_pi * j / minor_segments;
            const double r = major_radius + minor_radius * std::cos(v);
            mesh.positions.push_back({float(r * std::cos(u)), float(r * std::sin(u)),
                                      float(minor_radius * std::sin(v))});
        }
    }
    auto idx = [&](int i, int j) {
        return uint32_t((i % major_segments) * minor_segments + (j % minor_segments));
    };
    for (int i = 0; i < major_segments; ++i)
        for (int j = 0; j < minor_segments; ++j) {
            mesh.triangles.push_back({idx(i, j), idx(i + 1, j), idx(i + 1, j + 1)});
            mesh.triangles.push_back({idx(i, j), idx(i + 1, j + 1), idx(i, j + 1)});
        }
    return mesh;
}

TriangleMesh make_terrain(int nx, int ny, uint64_t seed) {
    TriangleMesh mesh;
    mesh.name = "terrain" + std::to_string(nx) + "x" + std::to_string(ny);
    std::mt19937_64 rng(seed);
    std::uniform_real_distribution<float> phase(0.0f, 6.2831853f);
    const float p1 = phase(rng), p2 = phase(rng), p3 = phase(rng);
    std::uniform_real_distribution<float> noise(-0.01f, 0.01f);
    for (int y = 0; y <= ny; ++y)
        for (int x = 0; x <= nx; ++x) {
            const float fx = float(x) / nx * 2 - 1, fy = float(y) / ny * 2 - 1;
            const float h = 0.15f * std::sin(5 * fx + p1) * std::cos(4 * fy + p2) +
                            0.05f * std::sin(17 * (fx + fy) + p3) + noise(rng);
            mesh.positions.push_back({fx, h, fy});
        }
    auto idx = [&](int x, int y) { return uint32_t(y * (nx + 1) + x); };
    for (int y = 0; y < ny; ++y)
        for (int x = 0; x < nx; ++x) {
            mesh.triangles.push_back({idx(x, y), idx(x, y + 1), idx(x + 1, y)});
            mesh.triangles.push_back({idx(x + 1, y), idx(x, y + 1), idx(x + 1, y + 1)});
        }
    return mesh;
}

TriangleMesh make_random_soup(size_t triangle_count, uint64_t seed, float box, float max_edge) {
    TriangleMesh mesh;
    mesh.name = "soup" + std::to_string(triangle_count);
    std::mt19937_64 rng(seed);
    std::uniform_real_distribution<float> centre(-box, box);
    std::uniform_real_distribution<float> offset(-max_edge / 2, max_edge / 2);
    mesh.positions.reserve(triangle_count * 3);
    mesh.triangles.reserve(triangle_count);
    for (size_t t = 0; t < triangle_count; ++t) {
        const Float3 c{centre(rng), centre(rng), centre(rng)};
        for (int k = 0; k < 3; ++k)
            mesh.positions.push_back({c[0] + offset(rng), c[1] + offset(rng), c[2] + offset(rng)});
        const uint32_t b = uint32_t(3 * t);
        mesh.triangles.push_back({b, b + 1, b + 2});
    }
    return mesh;
}

void Bounds::extend(const Float3& p) {
    for (int k = 0; k < 3; ++k) {
        lo[k] = std::fmin(lo[k], p[k]);
        hi[k] = std::fmax(hi[k], p[k]);
    }
}

Float3 Bounds::center() const {
    return {(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, (lo[2] + hi[2]) / 2};
}

float Bounds::diagonal() const {
    const double dx = hi[0] - lo[0], dy = hi[1] - lo[1], dz = hi[2] - lo[2];
    return float(std::sqrt(dx * dx + dy * dy + dz * dz));
}

Bounds bounds_of(const TriangleMesh& mesh) {
    Bounds b;
    for (const Triangle& t : mesh.triangles)
        for (uint32_t v : t) b.extend(mesh.positions[v]);
    return b;
}

float truncate_float(float value, unsigned bits) {
    const uint32_t mask = bits >= 32 ? 0u : ~((uint32_t(1) << bits) - 1u);
    return std::bit_cast<float>(std::bit_cast<uint32_t>(value) & mask);
}

Float3 truncate_position(const Float3& p, unsigned bits) {
    return {truncate_float(p[0], bits), truncate_float(p[1], bits), truncate_float(p[2], bits)};
}

}  // namespace clastrace::testsupport
