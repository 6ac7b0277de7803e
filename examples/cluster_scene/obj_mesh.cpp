// SPDX-License-Identifier: Apache-2.0
#include "obj_mesh.h"

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <fstream>

namespace cluster_scene {
namespace {

// Skips spaces and tabs; returns the next token (up to whitespace) or an empty view.
const char* nextToken(const char*& p, size_t& length) {
    while (*p == ' ' || *p == '\t' || *p == '\r') ++p;
    const char* start = p;
    while (*p && *p != ' ' && *p != '\t' && *p != '\r') ++p;
    length = size_t(p - start);
    return start;
}

}  // namespace

bool loadObj(const std::string& path, TriangleMesh& mesh, std::string& error) {
    std::ifstream in(path, std::ios::binary);
    if (!in) {
        error = path + ": cannot open: " + std::strerror(errno);
        return false;
    }
    mesh = {};
    std::string line;
    std::vector<uint32_t> corners;
    for (size_t lineNumber = 1; std::getline(in, line); ++lineNumber) {
        auto fail = [&](const std::string& what) {
            error = path + ":" + std::to_string(lineNumber) + ": " + what;
            return false;
        };
        const char* p = line.c_str();
        size_t length = 0;
        const char* keyword = nextToken(p, length);
        if (length == 1 && keyword[0] == 'v') {
            for (int axis = 0; axis < 3; ++axis) {
                const char* token = nextToken(p, length);
                if (length == 0) return fail("vertex with fewer than 3 coordinates");
                char* end = nullptr;
                const float value = std::strtof(token, &end);
                if (end != token + length)
                    return fail("coordinate '" + std::string(token, length) + "' is not a number");
                if (!std::isfinite(value))
                    return fail("coordinate '" + std::string(token, length) + "' is not finite");
                mesh.positions.push_back(value);
            }
        } else if (length == 1 && keyword[0] == 'f') {
            corners.clear();
            const long vertexCount = long(mesh.vertexCount());
            for (const char* token = nextToken(p, length); length > 0;
                 token = nextToken(p, length)) {
                char* end = nullptr;
                const long index = std::strtol(token, &end, 10);  // "7", "7/1", "7//3", "-2/..."
                if (end == token || (end != token + length && *end != '/'))
                    return fail("face corner '" + std::string(token, length) +
                                "' is not a vertex index");
                const long resolved = index < 0 ? vertexCount + index : index - 1;
                if (index == 0 || resolved < 0 || resolved >= vertexCount)
                    return fail("face corner " + std::to_string(index) +
                                " names no vertex (the file has " + std::to_string(vertexCount) +
                                " so far)");
                corners.push_back(uint32_t(resolved));
            }
            if (corners.size() < 3) return fail("face with fewer than 3 corners");
            for (size_t i = 1; i + 1 < corners.size(); ++i)
                mesh.indices.insert(mesh.indices.end(), {corners[0], corners[i], corners[i + 1]});
        }
    }
    if (mesh.indices.empty()) {
        error = path + ": no faces (an OBJ mesh needs 'f' lines)";
        return false;
    }
    return true;
}

void tileMesh(TriangleMesh& mesh, uint32_t copies) {
    if (copies <= 1 || mesh.positions.empty()) return;
    float low = mesh.positions[0], high = mesh.positions[0];
    for (size_t i = 0; i < mesh.positions.size(); i += 3)
        low = std::min(low, mesh.positions[i]), high = std::max(high, mesh.positions[i]);
    const float step = (high - low) * 1.1f + 1e-3f;  // a flat mesh still gets apart
    const size_t vertices = mesh.vertexCount(), indices = mesh.indices.size();
    mesh.positions.reserve(mesh.positions.size() * copies);
    mesh.indices.reserve(indices * copies);
    for (uint32_t c = 1; c < copies; ++c) {
        for (size_t v = 0; v < vertices; ++v) {
            mesh.positions.push_back(mesh.positions[3 * v] + step * float(c));
            mesh.positions.push_back(mesh.positions[3 * v + 1]);
            mesh.positions.push_back(mesh.positions[3 * v + 2]);
        }
        for (size_t i = 0; i < indices; ++i)
            mesh.indices.push_back(mesh.indices[i] + uint32_t(vertices * c));
    }
}

}  // namespace cluster_scene
