// SPDX-License-Identifier: Apache-2.0
// Decoding a served cluster BLAS into the triangles the driver's BLAS is built from: the BLAS the
// engine just wrote names its clusters, and each cluster's bytes give its triangles as the
// engine stored them (positions after truncation), so the driver traverses the same geometry the
// engine does.
#include "traceable_clusters.h"

#include <clastrace/engine/blas.h>
#include <clastrace/engine/cluster_format.h>

#include <cmath>
#include <limits>

namespace clastrace::capture {
namespace {

// The bytes of the engine object at `address` inside one region of `image`: empty when none.
std::span<const std::byte> object_bytes(const engine::MemoryImage& image, uint64_t address) {
    const engine::MemoryRegion* region = image.find_region(address);
    if (!region) return {};
    const uint64_t offset = address - region->base;
    const std::span<const std::byte> rest(region->bytes.data() + offset, region->size - offset);
    const uint32_t size = engine::object_size_from_header(rest);
    return size == 0 || size > rest.size() ? std::span<const std::byte>{} : rest.first(size);
}

// One cluster's triangles at their original indices into `triangles`, and their geometry
// indices; a triangle the cluster does not store (inactive) stays NaN, which the driver treats
// as inactive too, with geometry index 0xFFFFFFFF.
void cluster_triangles(std::span<const std::byte> clas, const engine::ObjectHeader& header,
                       std::vector<float>& triangles, std::vector<uint32_t>& geometry_indices) {
    uint32_t count = 0;
    for (uint32_t i = 0; i < header.triangle_count; ++i)
        count = std::max(count, engine::decode_triangle(clas, header, i).original_index + 1);
    triangles.assign(size_t(count) * 9, std::numeric_limits<float>::quiet_NaN());
    geometry_indices.assign(count, 0xFFFFFFFFu);
    for (uint32_t i = 0; i < header.triangle_count; ++i) {
        const engine::DecodedTriangle t = engine::decode_triangle(clas, header, i);
        for (int v = 0; v < 3; ++v)
            for (int axis = 0; axis < 3; ++axis)
                triangles[size_t(t.original_index) * 9 + v * 3 + axis] = t.v[v][axis];
        geometry_indices[t.original_index] = t.geometry_index_and_flags & 0xFFFFFFu;
    }
}

}  // namespace

bool decode_cluster_blas(const engine::MemoryImage& image, uint64_t address,
                         TraceableBlasGeometry& out, std::string& why) {
    const std::span<const std::byte> blas = object_bytes(image, address);
    const engine::BottomLevelCheck check = engine::read_bottom_level_header(blas);
    if (!check.header) {
        why = blas.empty() ? "no engine object at the destination" : check.error;
        return false;
    }
    const engine::BottomLevelHeader& header = *check.header;
    out.clusters.assign(header.input_reference_count, {});
    out.geometry_indices.assign(header.input_reference_count, {});
    for (uint32_t r = 0; r < header.reference_count; ++r) {
        engine::ClusterReference reference;
        std::memcpy(&reference,
                    blas.data() + header.references_offset + r * sizeof(engine::ClusterReference),
                    sizeof reference);
        const std::span<const std::byte> clas = object_bytes(image, reference.clas_address);
        const engine::HeaderCheck clas_check = engine::read_object_header(clas);
        if (!clas_check.header || reference.reference_index >= out.clusters.size()) {
            why = "reference " + std::to_string(reference.reference_index) +
                  " names no cluster in the engine's image";
            return false;
        }
        cluster_triangles(clas, *clas_check.header, out.clusters[reference.reference_index],
                          out.geometry_indices[reference.reference_index]);
    }
    return true;
}

}  // namespace clastrace::capture
