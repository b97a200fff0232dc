// CRC-32C (Castagnoli, reflected polynomial 0x82F63B78), the checksum of
// every section of our files. Slicing-by-8 table implementation.
#pragma once

#include <cstddef>
#include <cstdint>

namespace visloc {

// Extends `crc` (0 to start) over `size` bytes.
uint32_t crc32c(const void* data, size_t size, uint32_t crc = 0);

}  // namespace visloc
