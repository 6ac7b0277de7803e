// SPDX-License-Identifier: Apache-2.0
// A Vulkan program that names itself and its engine in Latin-1, as older programs do
// ("café", "moteur été"), then fills a buffer in one submission. The capture layer must write a
// trace (and a debug JSON) that the tools read: tests/capture/latin1_names_test.cpp.
#include "cluster_test_device.h"

#include <cstdio>

int main() {
    clastrace::testapp::ClusterTestDevice c;
    c.createInstance("caf\xE9", {}, "moteur \xE9t\xE9");
    c.createDevice();
    clastrace::testapp::Buffer buffer = c.makeBuffer(256, 0);
    VkCommandBuffer cb = c.beginCommands();
    vkCmdFillBuffer(cb, buffer.buffer, 0, buffer.size, 0x01020304u);
    c.submitAndWait(cb);
    c.destroy();
    std::puts("filled");
    return 0;
}
