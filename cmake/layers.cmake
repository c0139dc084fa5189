# The layer table: each library module and the modules below it that it may include and link.
# Arrows point down only (no back arrows, no circles):
#   core <- session <- capture ; session <- heightfield <- calibration ; session <- maps ;
#   core <- brdf <- render ; core <- assets ; maps <- compare ; sim above reconstruction,
#   calibration, maps, render and assets (docs/architecture.md, "Modules");
#   app/, tests/, bench/, fuzz/ (and the *_test.cc files beside each library source) on top.
# Checked at configure time on the CMake targets' links (mesoscan_check_layer_links below) and
# by the ctest test house_layers on the sources' #include lines (cmake/check_layers.cmake).
set(MESOSCAN_LIBRARY_MODULES
    core session capture heightfield calibration maps brdf render assets sim compare)
set(MESOSCAN_LAYER_core "")
set(MESOSCAN_LAYER_session core)
set(MESOSCAN_LAYER_capture core session)
set(MESOSCAN_LAYER_heightfield core session)
set(MESOSCAN_LAYER_calibration core session heightfield)
set(MESOSCAN_LAYER_maps core session)
set(MESOSCAN_LAYER_brdf core)
set(MESOSCAN_LAYER_render core brdf)
set(MESOSCAN_LAYER_assets core)
set(MESOSCAN_LAYER_sim core session heightfield calibration maps brdf render assets)
set(MESOSCAN_LAYER_compare core maps)

# Fails the configuration if a module's target links a library module the table does not
# allow it (PUBLIC or PRIVATE).
function(mesoscan_check_layer_links)
  foreach(module ${MESOSCAN_LIBRARY_MODULES})
    if(NOT TARGET mesoscan_${module})
      continue()
    endif()
    get_target_property(libs mesoscan_${module} LINK_LIBRARIES)
    if(NOT libs)
      continue()
    endif()
    foreach(lib ${libs})
      if(lib MATCHES "^mesoscan_(.+)$")
        set(used ${CMAKE_MATCH_1})
        if(used IN_LIST MESOSCAN_LIBRARY_MODULES AND NOT used IN_LIST MESOSCAN_LAYER_${module})
          message(FATAL_ERROR "layer table (cmake/layers.cmake): mesoscan_${module} links "
                              "mesoscan_${used}, a module ${module}/ may not use")
        endif()
      endif()
    endforeach()
  endforeach()
endfunction()
