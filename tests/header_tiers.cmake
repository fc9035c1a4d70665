# Holds the public headers to their two tiers (README, "Headers"):
#   cmake -DSRC=<source dir> -DPRODUCT=a.h,b.h -DLAB=c.h,d.h -P this file
# PRODUCT and LAB are CMakeLists.txt's RP_PRODUCT_HEADERS and
# RP_LAB_HEADERS, the lists the install rule installs. It fails when a
# header in include/ is in neither list or in both, when a header's
# opening line does not say its tier, when a product header includes a lab
# header, or when a sample includes one: an app copies the samples, and
# what they include is what an app is told it needs.
string(REPLACE "," ";" product "${PRODUCT}")
string(REPLACE "," ";" lab "${LAB}")
set(problems "")

file(GLOB headers RELATIVE ${SRC}/include ${SRC}/include/*.h)
foreach(h ${headers})
  list(FIND product ${h} in_product)
  list(FIND lab ${h} in_lab)
  if(in_product EQUAL -1 AND in_lab EQUAL -1)
    string(APPEND problems "include/${h}: in neither tier's list\n")
  elseif(NOT in_product EQUAL -1 AND NOT in_lab EQUAL -1)
    string(APPEND problems "include/${h}: in both tiers' lists\n")
  endif()
endforeach()
foreach(h ${product} ${lab})
  if(NOT EXISTS ${SRC}/include/${h})
    string(APPEND problems "include/${h}: listed but missing\n")
  endif()
endforeach()

# Appends to `problems` each raypace header `path` includes that is not
# in `allowed`.
function(rp_only_includes path allowed)
  file(STRINGS ${path} lines REGEX "^#include [\"<]raypace[a-z_]*\\.h[\">]")
  file(RELATIVE_PATH rel ${SRC} ${path})
  foreach(l ${lines})
    string(REGEX REPLACE "^#include [\"<](raypace[a-z_]*\\.h)[\">].*" "\\1"
      name "${l}")
    list(FIND allowed ${name} i)
    if(i EQUAL -1)
      string(APPEND problems "${rel}: includes ${name}, not a product "
        "header\n")
    endif()
  endforeach()
  set(problems "${problems}" PARENT_SCOPE)
endfunction()

# Appends to `problems` when header `h` does not open with "/* TIER tier".
function(rp_says_tier h tier)
  file(STRINGS ${SRC}/include/${h} first LIMIT_COUNT 1)
  if(NOT first MATCHES "^/\\* ${tier} tier")
    string(APPEND problems "include/${h}: does not open by saying it is "
      "the ${tier} tier\n")
  endif()
  set(problems "${problems}" PARENT_SCOPE)
endfunction()

foreach(h ${product})
  rp_says_tier(${h} Product)
  rp_only_includes(${SRC}/include/${h} "${product}")
endforeach()
foreach(h ${lab})
  rp_says_tier(${h} Lab)
endforeach()
file(GLOB samples ${SRC}/samples/*.c)
foreach(s ${samples})
  rp_only_includes(${s} "${product}")
endforeach()

if(problems)
  message(FATAL_ERROR "header tiers:\n${problems}")
endif()
message(STATUS "header tiers: ${PRODUCT} | ${LAB}")
