// SPDX-License-Identifier: Apache-2.0
// Runs examples/rt_frame_loop on lavapipe 25 alone or under `clastrace capture` (the two
// rt-driver test files of tests/examples share it). Skips when the ray-tracing driver is missing.
#pragma once

#include "layer_launch_test.h"

#include <clastrace/testsupport/test_driver.h>
#include <gtest/gtest.h>

#include <cstdint>
#include <optional>
#include <string>

namespace rt_frame_loop_test {

class RtFrameLoopLaunch : public clastrace::layer_launch::RayTracingLaunchTest {
protected:
    RtFrameLoopLaunch(std::string directory_prefix, uint32_t frames, uint32_t width,
                      uint32_t height)
        : RayTracingLaunchTest(std::move(directory_prefix)),
          frames_(frames),
          width_(width),
          height_(height) {}

    std::string app(const std::string& args) const {
        return std::string(RT_FRAME_LOOP_APP) + " --frames " + std::to_string(frames_) +
               " --width " + std::to_string(width_) + " --height " + std::to_string(height_) + " " +
               args;
    }
    // The program on lavapipe 25 without the layer.
    clastrace::layer_launch::ProcessResult run_alone(const std::string& args) {
        return runOnDriver(app(args));
    }
    // The program under `clastrace capture` writing dir/frames.clt.
    clastrace::layer_launch::ProcessResult capture(const std::string& options,
                                                   const std::string& args) {
        return captureOnDriver(dir / "frames.clt", app(args), options);
    }

    uint32_t frames_, width_, height_;
};

}  // namespace rt_frame_loop_test
