// SPDX-License-Identifier: Apache-2.0
// dispatch_writes_infos: a GPU-driven engine's culling pass, reduced to what the bug needs: it
// writes the cluster build's src infos (here copied word by word from the visible set).
#version 460
layout(local_size_x = 64) in;

layout(set = 0, binding = 0, std430) readonly buffer Visible {
    uint words[];
} visible;

layout(set = 0, binding = 1, std430) writeonly buffer BuildInfos {
    uint words[];
} build_infos;

layout(push_constant) uniform Count {
    uint words;
} count;

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i < count.words) build_infos.words[i] = visible.words[i];
}
