# The code blocks of client/lib/README.md compile and link: the ```c blocks,
# in order, as one C99 file and as one C++11 file, the ```cpp blocks as
# C++11 and C++17, each with -Wall -Wextra -Werror -pedantic, against the
# tree's headers and static library. Run by ctest:
#   cmake -DREADME=... -DCC=... -DCXX=... -DINCLUDES="a|b" -DLIB=... [-DFLAGS=...] -DWORK=...
#         -P snippets.cmake
file(READ ${README} text)
if(DEFINED WORK)
  file(MAKE_DIRECTORY ${WORK})
endif()
# Semicolons would split CMake lists: they travel as a placeholder.
string(REPLACE ";" "@SEMICOLON@" text "${text}")
# Line by line: a block runs from its fence (```c or ```cpp) to the next
# line that is ``` alone.
string(REPLACE "\n" ";" lines "${text}")
set(c_src "")
set(cpp_src "")
set(nc 0)
set(ncpp 0)
set(in "")
foreach(line IN LISTS lines)
  if(in STREQUAL "")
    if(line STREQUAL "```c")
      set(in c)
      math(EXPR nc "${nc} + 1")
    elseif(line STREQUAL "```cpp")
      set(in cpp)
      math(EXPR ncpp "${ncpp} + 1")
    endif()
  elseif(line STREQUAL "```")
    set(in "")
  else()
    string(APPEND ${in}_src "${line}\n")
  endif()
endforeach()
if(NOT in STREQUAL "")
  message(FATAL_ERROR "snippets: a ${in} block of ${README} is not closed")
endif()
if(nc LESS 5 OR ncpp LESS 1)
  message(FATAL_ERROR "snippets: found ${nc} C and ${ncpp} C++ blocks in ${README}")
endif()
string(REPLACE "@SEMICOLON@" ";" c_src "${c_src}")
# -DBODY=FILE: only write the C blocks there, for a test that runs them.
if(DEFINED BODY)
  file(WRITE ${BODY} "${c_src}")
  return()
endif()
# A program around them, so that they are linked too.
set(main "\nint main(void) { return 0; }\n")
string(REPLACE "@SEMICOLON@" ";" cpp_src "${cpp_src}")
file(WRITE ${WORK}/snippets.c "${c_src}${main}")
file(WRITE ${WORK}/snippets_c.cpp "${c_src}${main}")
file(WRITE ${WORK}/snippets.cpp "${cpp_src}${main}")

set(inc "")
string(REPLACE "|" ";" INCLUDES "${INCLUDES}")
foreach(d IN LISTS INCLUDES)
  list(APPEND inc -I${d})
endforeach()
set(warn -Wall -Wextra -Werror -pedantic -Wno-unused-function)
separate_arguments(flags UNIX_COMMAND "${FLAGS}")
# The static library and what it links (OpenSSL), "|"-separated.
string(REPLACE "|" ";" LIB "${LIB}")
function(build name compiler std src)
  execute_process(COMMAND ${compiler} ${std} ${warn} ${flags} ${inc} ${src} ${LIB}
                          -o ${WORK}/${name}
                  RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE out)
  if(rc)
    message(FATAL_ERROR "snippets: ${name} (${std}) does not build:\n${out}")
  endif()
  message(STATUS "snippets: ${name} builds as ${std}")
endfunction()
build(c99 ${CC} -std=c99 ${WORK}/snippets.c)
build(c_as_cpp11 ${CXX} -std=c++11 ${WORK}/snippets_c.cpp)
build(cpp11 ${CXX} -std=c++11 ${WORK}/snippets.cpp)
build(cpp17 ${CXX} -std=c++17 ${WORK}/snippets.cpp)
message(STATUS "snippets: ${nc} C blocks and ${ncpp} C++ blocks of ${README} build")
