// SPDX-License-Identifier: Apache-2.0
#include "frame_scene.h"

#include <cmath>
#include <cstdio>
#include <fstream>
#include <limits>

namespace rt_frame_loop {

std::vector<Vec3> mesh_vertices(uint32_t mesh, uint64_t frame) {
    const float phase = float(frame % 64) * 0.35f;
    if (mesh == 0) {  // a quad whose top edge moves up and down: two triangles
        const float top = 0.3f + 0.35f * std::sin(phase);
        return {{-0.8f, -0.6f, 0.f}, {-0.1f, -0.6f, 0.f}, {-0.1f, top, 0.f},
                {-0.8f, -0.6f, 0.f}, {-0.1f, top, 0.f},   {-0.8f, top, 0.f}};
    }
    // A triangle turning about its centre, plus a small fixed one below it.
    std::vector<Vec3> v;
    for (int i = 0; i < 3; ++i) {
        const float a = phase + float(i) * 2.0943951f;
        v.push_back({0.35f * std::cos(a), 0.35f * std::sin(a), 0.f});
    }
    v.push_back({-0.2f, -0.75f, 0.f});
    v.push_back({0.2f, -0.75f, 0.f});
    v.push_back({0.f, -0.5f, 0.f});
    return v;
}

void instance_transform(uint32_t mesh, float out[12]) {
    const float identity[12] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0};
    for (int i = 0; i < 12; ++i) out[i] = identity[i];
    if (mesh == 1) {  // moved right and slightly forward (closer to the rays' origin)
        out[3] = 0.45f;
        out[7] = 0.1f;
        out[11] = -0.25f;
    }
}

uint32_t hit_colour(uint32_t instance, uint32_t primitive) {
    const uint32_t base = instance == 0 ? 0x00e05030u : 0x003060e0u;  // ABGR: R low byte
    return 0xff000000u | (base + ((primitive * 0x40u) << 8));
}

void pixel_ray(uint32_t x, uint32_t y, uint32_t width, uint32_t height, Vec3& origin, Vec3& dir) {
    const float u = (float(x) + 0.5f) / float(width), v = (float(y) + 0.5f) / float(height);
    origin = {u * 2.f - 1.f, 1.f - v * 2.f, -1.f};
    dir = {0.f, 0.f, 1.f};
}

namespace {

struct Hit {
    float t = std::numeric_limits<float>::infinity();
    uint32_t instance = 0, primitive = 0;
    bool near_edge = false;
};

// Rays run along +z, so the test is 2D: barycentrics of the origin's (x, y) in the projected
// triangle, and t = z of the hit point minus the origin's z.
void intersect(const Vec3& o, const Vec3 w[3], uint32_t instance, uint32_t primitive, Hit& best) {
    const double ax = w[0].x, ay = w[0].y, bx = w[1].x, by = w[1].y, cx = w[2].x, cy = w[2].y;
    const double area = (bx - ax) * (cy - ay) - (cx - ax) * (by - ay);
    if (std::fabs(area) < 1e-12) return;
    const double b1 = ((o.x - ax) * (cy - ay) - (cx - ax) * (o.y - ay)) / area;
    const double b2 = ((bx - ax) * (o.y - ay) - (o.x - ax) * (by - ay)) / area;
    const double b0 = 1.0 - b1 - b2;
    const double eps = 1e-4;
    const bool inside = b0 >= 0 && b1 >= 0 && b2 >= 0;
    const bool near = std::fabs(b0) < eps || std::fabs(b1) < eps || std::fabs(b2) < eps;
    if (near && (inside || (b0 > -eps && b1 > -eps && b2 > -eps))) best.near_edge = true;
    if (!inside) return;
    const double z = b0 * w[0].z + b1 * w[1].z + b2 * w[2].z;
    const float t = float(z - o.z);
    if (t < 0.f || t >= best.t) return;
    best.t = t;
    best.instance = instance;
    best.primitive = primitive;
}

Vec3 transform_point(const float m[12], const Vec3& p) {
    return {m[0] * p.x + m[1] * p.y + m[2] * p.z + m[3],
            m[4] * p.x + m[5] * p.y + m[6] * p.z + m[7],
            m[8] * p.x + m[9] * p.y + m[10] * p.z + m[11]};
}

}  // namespace

ReferenceImage trace_reference(uint64_t frame, uint32_t width, uint32_t height) {
    std::vector<std::vector<Vec3>> world(kMeshCount);
    for (uint32_t mesh = 0; mesh < kMeshCount; ++mesh) {
        float m[12];
        instance_transform(mesh, m);
        for (const Vec3& p : mesh_vertices(mesh, frame))
            world[mesh].push_back(transform_point(m, p));
    }
    ReferenceImage image;
    image.pixels.resize(size_t(width) * height);
    image.ambiguous.resize(size_t(width) * height);
    for (uint32_t y = 0; y < height; ++y)
        for (uint32_t x = 0; x < width; ++x) {
            Vec3 o, d;
            pixel_ray(x, y, width, height, o, d);
            Hit best;
            for (uint32_t mesh = 0; mesh < kMeshCount; ++mesh)
                for (size_t tri = 0; tri + 2 < world[mesh].size(); tri += 3)
                    intersect(o, &world[mesh][tri], mesh, uint32_t(tri / 3), best);
            const size_t i = size_t(y) * width + x;
            image.pixels[i] =
                std::isinf(best.t) ? kBackground : hit_colour(best.instance, best.primitive);
            image.ambiguous[i] = best.near_edge;
        }
    return image;
}

uint64_t image_checksum(const std::vector<uint32_t>& pixels) {
    uint64_t hash = 0xcbf29ce484222325ull;
    for (uint32_t p : pixels)
        for (int b = 0; b < 4; ++b) {
            hash ^= (p >> (8 * b)) & 0xffu;
            hash *= 0x100000001b3ull;
        }
    return hash;
}

bool write_ppm(const std::string& path, const std::vector<uint32_t>& pixels, uint32_t width,
               uint32_t height, std::string& error) {
    std::ofstream out(path, std::ios::binary);
    out << "P6\n" << width << " " << height << "\n255\n";
    for (uint32_t p : pixels) {
        const char rgb[3] = {char(p & 0xff), char((p >> 8) & 0xff), char((p >> 16) & 0xff)};
        out.write(rgb, 3);
    }
    if (!out) error = path + ": cannot be written";
    return bool(out);
}

bool read_ppm(const std::string& path, std::vector<uint32_t>& pixels, uint32_t& width,
              uint32_t& height, std::string& error) {
    std::ifstream in(path, std::ios::binary);
    std::string magic;
    uint32_t max_value = 0;
    in >> magic >> width >> height >> max_value;
    in.get();  // the one whitespace byte before the samples
    if (!in || magic != "P6" || max_value != 255 || width == 0 || height == 0) {
        error = path + ": not a binary PPM with 8-bit samples";
        return false;
    }
    pixels.assign(size_t(width) * height, 0);
    for (uint32_t& p : pixels) {
        unsigned char rgb[3];
        if (!in.read((char*)rgb, 3)) {
            error = path + ": ends inside the pixel data";
            return false;
        }
        p = 0xff000000u | rgb[0] | (uint32_t(rgb[1]) << 8) | (uint32_t(rgb[2]) << 16);
    }
    return true;
}

}  // namespace rt_frame_loop
