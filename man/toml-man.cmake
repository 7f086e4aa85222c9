# Writes turncal.toml(5): the page's head, the keys from the commented
# configuration (toml-man.awk), its tail. Run by man/CMakeLists.txt.
cmake_policy(SET CMP0053 NEW)  # @VAR@ left alone in quoted arguments
file(READ ${CMAKE_CURRENT_LIST_DIR}/turncal.toml.5.head head)
string(REPLACE "@VERSION@" "${VERSION}" head "${head}")
execute_process(
  COMMAND ${AWK} -v only=table.cia402 -v onlyfile=${SRC}/config/stands/cia402/turncal.toml
    -f ${CMAKE_CURRENT_LIST_DIR}/toml-man.awk
    ${SRC}/config/turncal.toml ${SRC}/config/stands/cia402/turncal.toml
  OUTPUT_VARIABLE body
  RESULT_VARIABLE rc)
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "toml-man.awk failed (${rc})")
endif()
file(READ ${CMAKE_CURRENT_LIST_DIR}/turncal.toml.5.tail tail)
file(WRITE ${OUT}.tmp "${head}${body}${tail}")
file(RENAME ${OUT}.tmp ${OUT})
