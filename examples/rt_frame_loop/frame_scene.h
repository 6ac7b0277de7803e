// SPDX-License-Identifier: Apache-2.0
// rt_frame_loop's scene without Vulkan: the vertices of each mesh at each frame (animated on the
// host), the instances over them, the rays of each pixel and the colour of a hit, so a test can
// trace the same frame on the CPU and compare it with what the driver traced.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

namespace rt_frame_loop {

// One BLAS per mesh; one TLAS instance per mesh, instanceCustomIndex = mesh index.
constexpr uint32_t kMeshCount = 2;
constexpr uint32_t kBackground = 0xff202020u;  // RGBA8 packed as the shader writes it

struct Vec3 {
    float x, y, z;
};

// Triangle list (3 vertices per triangle) of `mesh` at `frame`, in the mesh's own space.
std::vector<Vec3> mesh_vertices(uint32_t mesh, uint64_t frame);
// Row-major 3x4 object-to-world transform of instance `mesh` (VkTransformMatrixKHR's layout).
void instance_transform(uint32_t mesh, float out[12]);
// The shaded colour of a hit (what shaders/trace_pixels.comp computes).
uint32_t hit_colour(uint32_t instance, uint32_t primitive);

// Pixel (x, y)'s ray: orthographic, along +z from z = -1.
void pixel_ray(uint32_t x, uint32_t y, uint32_t width, uint32_t height, Vec3& origin, Vec3& dir);

struct ReferenceImage {
    std::vector<uint32_t> pixels;  // width * height, row 0 at the top
    // Pixels whose ray passes within a rounding error of a triangle's edge: the driver may
    // resolve them either way, so comparisons skip them.
    std::vector<bool> ambiguous;
};
// Traces frame `frame` on the CPU: the image the driver should produce.
ReferenceImage trace_reference(uint64_t frame, uint32_t width, uint32_t height);

// FNV-1a 64 of the pixels' bytes: the checksum the program prints.
uint64_t image_checksum(const std::vector<uint32_t>& pixels);
// Binary PPM (P6), alpha dropped. False with `error` when the file cannot be written.
bool write_ppm(const std::string& path, const std::vector<uint32_t>& pixels, uint32_t width,
               uint32_t height, std::string& error);
// Reads a P6 written by write_ppm back as packed pixels (alpha 0xff). False with `error`.
bool read_ppm(const std::string& path, std::vector<uint32_t>& pixels, uint32_t& width,
              uint32_t& height, std::string& error);

}  // namespace rt_frame_loop
