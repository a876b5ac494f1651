// The parts of ASPRS LAS 1.4 (R15) that both the LAS reader
// (preprocess/readers/las_reader.cpp) and the LAS export
// (export/laz_export.cpp) lay out: the point data record formats (tables
// 7-17), the VLRs they read or write, and the Extra Bytes descriptor (table 24).
#pragma once

#include <cstddef>
#include <cstdint>
#include <cstring>
#include <string>

namespace surfcast::las {

// A point format's record bytes before any extra bytes, and where its GPS
// time, RGB, NIR and wave packet start (0: the format has none).
struct FormatLayout {
    size_t bytes, gps, rgb, nir, wave;
};
inline constexpr FormatLayout kFormats[11] = {
    {20, 0, 0, 0, 0},   {28, 20, 0, 0, 0},  {26, 0, 20, 0, 0},  {34, 20, 28, 0, 0},  {57, 20, 0, 0, 28},  {63, 20, 28, 0, 34},
    {30, 22, 0, 0, 0},  {36, 22, 30, 0, 0}, {38, 22, 30, 36, 0}, {59, 22, 0, 0, 30}, {67, 22, 30, 36, 38}};

inline constexpr char kSpecUser[] = "LASF_Spec", kProjectionUser[] = "LASF_Projection";
inline constexpr uint16_t kExtraBytesRecord = 4;
inline constexpr uint16_t kWktRecord = 2112, kGeoKeysRecord = 34735, kGeoDoublesRecord = 34736, kGeoAsciiRecord = 34737;

// An Extra Bytes descriptor: its bytes, and the bytes of a scalar of data
// type 1-10 (u8, i8, u16, i16, u32, i32, u64, i64, f32, f64; 0: none).
inline constexpr size_t kDescriptorBytes = 192;
inline constexpr size_t kTypeBytes[11] = {0, 1, 1, 2, 2, 4, 4, 8, 8, 4, 8};

// A descriptor's name (its 32 bytes from byte 4, up to the first zero).
inline std::string descriptorName(const uint8_t* descriptor) {
    const char* name = reinterpret_cast<const char*>(descriptor + 4);
    return std::string(name, strnlen(name, 32));
}

}  // namespace surfcast::las
