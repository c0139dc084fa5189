#pragma once
// JSON through nlohmann-json, plus helpers that read a key with a clear error naming the file
// and the key path ("session.json: rig.camera.K: expected a 3x3 array of numbers").

#include <filesystem>
#include <nlohmann/json.hpp>
#include <string>

#include "core/transform.h"

namespace mesoscan {

using Json = nlohmann::json;

// Parses a JSON file; throws Error naming the file and the parse position on failure.
Json ReadJsonFile(const std::filesystem::path& path);
// Writes pretty JSON (2-space indent) atomically.
void WriteJsonFile(const std::filesystem::path& path, const Json& j);

// Matrices as row-major nested arrays.
Json MatrixToJson(const Eigen::MatrixXd& m);

}  // namespace mesoscan
