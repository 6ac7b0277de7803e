// SPDX-License-Identifier: Apache-2.0
// The image examples/rt_frame_loop's shader traces, traced instead on the engine's replayed
// structures: a replay observer that follows each ray-query dispatch's top level (set 0,
// binding 0) and keeps the last frame. The E2E and pre-range tests compare it with the driver's.
#pragma once

#include "frame_scene.h"

#include <clastrace/engine/nv_trace.h>
#include <clastrace/replay/replay_observer.h>
#include <clastrace/replay/replayer.h>
#include <clastrace/traces/trace_generated.h>
#include <clastrace/traces/trace_reader.h>

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

namespace rt_frame_loop {

class EngineImage : public clastrace::replay::ReplayObserver {
public:
    EngineImage(uint32_t width, uint32_t height) : width_(width), height_(height) {}

    void on_command(const clastrace::replay::ReplayedCommand& c) override {
        const auto* dispatch = c.record->body_as_CmdDispatch();
        if (!dispatch || !dispatch->ray_query() || !dispatch->acceleration_structures()) return;
        ++dispatches;
        uint64_t top_level = 0;
        for (const auto* b : *dispatch->acceleration_structures())
            if (b->set() == 0 && b->binding() == 0 && b->source() == 0)
                top_level = c.engine_structure_address(b->acceleration_structure());
        std::string error;
        std::vector<clastrace::engine::Finding> findings;
        auto scene = clastrace::engine::NvScene::open(*c.memory, top_level, &findings, &error);
        if (!scene) {
            errors.push_back(error.empty() ? "no top level" : error);
            return;
        }
        instances_reached = scene->instances_reached();
        pixels.assign(size_t(width_) * height_, 0);
        for (uint32_t y = 0; y < height_; ++y)
            for (uint32_t x = 0; x < width_; ++x)
                pixels[size_t(y) * width_ + x] = shade(*scene, x, y);
    }

    size_t dispatches = 0;
    uint32_t instances_reached = 0;
    std::vector<std::string> errors;
    std::vector<uint32_t> pixels;

private:
    // As shaders/trace_pixels.comp shades a pixel.
    uint32_t shade(const clastrace::engine::NvScene& scene, uint32_t x, uint32_t y) const {
        Vec3 o, d;
        pixel_ray(x, y, width_, height_, o, d);
        const clastrace::engine::Ray ray{{o.x, o.y, o.z}, 0.0f, {d.x, d.y, d.z}, 100.0f};
        const clastrace::engine::NvHit hit =
            scene.closest(ray, clastrace::engine::kRayFlagOpaque, 0xff);
        return hit.hit ? hit_colour(hit.instance_custom_index, hit.primitive_index) : kBackground;
    }

    uint32_t width_, height_;
};

// Replays `trace` (named by its file name in the report) with an EngineImage watching.
inline EngineImage replay_engine_image(const std::filesystem::path& trace, uint32_t width,
                                       uint32_t height) {
    EngineImage engine(width, height);
    clastrace::traces::TraceError error;
    auto reader = clastrace::traces::TraceReader::open(trace.string(), &error);
    if (!reader) {
        engine.errors.push_back(error.message);
        return engine;
    }
    clastrace::replay::ReplayOptions options;
    options.observer = &engine;
    clastrace::replay::replay_trace(*reader, trace.filename().string(), options);
    return engine;
}

}  // namespace rt_frame_loop
