// COG export through GDAL's COG driver (CreateCopy only; it builds overviews in a temporary
// file). The output is written under a temporary name and renamed when GDAL is done.
#include <gdal_priv.h>

#include <filesystem>

#include "rolamos/error.hpp"
#include "rolamos/cog_export.hpp"
#include "raster/gdal_setup.h"
#include "util/files.h"

namespace rolamos {

bool CogOptions::IsValid(std::string* error) const {
  if (quality < 1 || quality > 100) {
    *error = "quality " + std::to_string(quality) + " is outside 1..100";
    return false;
  }
  if (tile_size != 256 && tile_size != 512) {
    *error = "tile size " + std::to_string(tile_size) + " is not supported; use 256 or 512";
    return false;
  }
  return true;
}

namespace {

int CPL_STDCALL GdalProgress(double fraction, const char*, void* data) {
  const auto* fn = static_cast<const ProgressFn*>(data);
  if (fn && *fn) (*fn)(fraction);
  return TRUE;
}

}  // namespace

void ExportCog(const std::string& source, const std::string& output, const CogOptions& options,
               const ProgressFn& progress) {
  std::string error;
  if (!options.IsValid(&error)) Fail(output, error);
  EnsureGdal();
  TakeGdalError();  // report only this export's errors
  GDALDatasetUniquePtr src(GDALDataset::Open(source.c_str(), GDAL_OF_RASTER | GDAL_OF_READONLY));
  if (!src) Fail(source, "GDAL cannot open it: " + TakeGdalError());
  GDALDriver* driver = GetGDALDriverManager()->GetDriverByName("COG");
  if (!driver) Fail(output, "this GDAL has no COG driver");
  // GDAL's COG driver keeps an alpha band as a mask by itself where JPEG cannot hold it.
  const std::string codec = options.compression == Compression::kNone       ? "NONE"
                            : options.compression == Compression::kJpegMask ? "JPEG"
                                                                            : ToUpper(CompressionName(options.compression));
  CPLStringList opts;
  opts.SetNameValue("COMPRESS", codec.c_str());
  opts.SetNameValue("BLOCKSIZE", std::to_string(options.tile_size).c_str());
  opts.SetNameValue("BIGTIFF", "IF_SAFER");
  opts.SetNameValue("NUM_THREADS", "ALL_CPUS");
  opts.SetNameValue("OVERVIEWS", "AUTO");  // reuses the source's levels when it has them
  opts.SetNameValue("RESAMPLING", "AVERAGE");
  if (options.compression == Compression::kJpeg || options.compression == Compression::kJpegMask ||
      options.compression == Compression::kWebp)
    opts.SetNameValue("QUALITY", std::to_string(options.quality).c_str());
  if (options.compression == Compression::kDeflate || options.compression == Compression::kZstd)
    opts.SetNameValue("PREDICTOR", "YES");
  // GDAL picks the driver from the name: keep ".tif" at the end of the temporary name.
  const std::string tmp = TemporarySibling(output) + ".tif";
  GDALDatasetUniquePtr out(driver->CreateCopy(tmp.c_str(), src.get(), FALSE, opts.List(),
                                              GdalProgress, const_cast<ProgressFn*>(&progress)));
  if (!out) {
    std::filesystem::remove(tmp);
    Fail(output, "GDAL's COG driver failed: " + TakeGdalError());
  }
  out.reset();
  RenameFile(tmp, output);
}

}  // namespace rolamos
