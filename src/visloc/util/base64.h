#pragma once
// Base64 (RFC 4648, standard alphabet, padded): binary arrays inside JSON and
// HTML (the viewer's page).
#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace visloc {

std::string base64_encode(const void* data, size_t size);
// nullopt on any character outside the alphabet or a bad length/padding.
std::optional<std::vector<uint8_t>> base64_decode(std::string_view text);

}  // namespace visloc
