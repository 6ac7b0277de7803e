// SPDX-License-Identifier: Apache-2.0
#include "clastrace/trace_building/trace_header.h"

#include <utility>

namespace clastrace::trace_building {

fbs::TraceHeaderT trace_header(std::string device_name, std::string driver_name,
                               std::string capture_tool) {
    fbs::TraceHeaderT h;
    h.device = std::make_unique<fbs::DeviceInfoT>();
    h.device->name = std::move(device_name);
    h.device->driver_name = std::move(driver_name);
    h.capture = std::make_unique<fbs::CaptureSettingsT>();
    h.capture->capture_tool = std::move(capture_tool);
    return h;
}

std::unique_ptr<fbs::ClusterPropertiesT> cluster_properties(const engine::EngineProperties& e) {
    auto p = std::make_unique<fbs::ClusterPropertiesT>();
    p->max_vertices_per_cluster = e.max_vertices_per_cluster;
    p->max_triangles_per_cluster = e.max_triangles_per_cluster;
    p->cluster_scratch_byte_alignment = e.cluster_scratch_byte_alignment;
    p->cluster_byte_alignment = e.cluster_byte_alignment;
    p->cluster_template_byte_alignment = e.cluster_template_byte_alignment;
    p->cluster_bottom_level_byte_alignment = e.cluster_bottom_level_byte_alignment;
    p->cluster_template_bounds_byte_alignment = e.cluster_template_bounds_byte_alignment;
    p->max_cluster_geometry_index = e.max_cluster_geometry_index;
    return p;
}

}  // namespace clastrace::trace_building
