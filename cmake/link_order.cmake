# Start-up time of the tools: Debian builds its libraries with BIND_NOW, so at every start the
# dynamic loader resolves each symbol of the ~280 libraries OpenCV, GDAL and OpenImageIO bring in,
# searching the libraries in breadth-first order of the executable's NEEDED list. Libraries that
# resolve many symbols to themselves (OpenVDB, 57,000 of its own template symbols, found ~110
# libraries deep) made `rolamos --help` take 0.20 s, most of it in that search. Naming the
# heaviest first puts them at the head of the search: 0.13 s (bench/RESULTS.md, session 27).
# Every library listed is already loaded through GDAL, OpenImageIO or OpenCV; one that is
# missing is skipped, so the order is an optimisation, never a new dependency. Ordered by the
# number of symbols bound to each (LD_DEBUG=bindings).
set(ROLAMOS_HEAVY_LIBRARIES
  libopenvdb.so.10.0 libc.so.6 libxerces-c-3.2.so libgdal.so.32 libstdc++.so.6 libgeos.so.3.11.1
  libcrypto.so.3 libopencv_core.so.406 libproj.so.25 libOpenImageIO.so.2.4 libprotobuf.so.32
  libdcmdata.so.17 libpoppler.so.126 libgdcmMSFF.so.3.0 libkmldom.so.1 libsqlite3.so.0
  libnetcdf.so.19 libglib-2.0.so.0 libOpenEXR-3_1.so.30 libhdf5_serial.so.103
  liblog4cplus-2.0.so.3 libIex-3_1.so.30 libOpenColorIO.so.2.1 libspatialite.so.7)

function(rolamos_search_heavy_libraries_first target)
  set(paths)
  foreach(soname IN LISTS ROLAMOS_HEAVY_LIBRARIES)
    find_library(_rolamos_heavy NAMES ${soname} NO_CACHE)
    if(_rolamos_heavy)
      list(APPEND paths ${_rolamos_heavy})
    endif()
    unset(_rolamos_heavy)
  endforeach()
  if(paths)
    # Before the objects, so that they head the NEEDED list; kept even if nothing refers to them.
    target_link_options(${target} BEFORE PRIVATE "LINKER:--no-as-needed" ${paths})
  endif()
endfunction()
