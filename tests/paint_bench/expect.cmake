# Runs one command and checks its exit code and output (ctest's PASS_REGULAR_EXPRESSION alone
# ignores the exit code).
#   cmake -DCMD=PROGRAM -DARGS="a|b|c" -DEXIT=N [-DREGEX=RE] [-DFILE=PATH -DFILE_REGEX=RE]
#         -P expect.cmake
# ARGS: the arguments, separated by '|'. REGEX: must match stdout + stderr. FILE: removed before
# the run; afterwards it must exist and match FILE_REGEX.
string(REPLACE "|" ";" args "${ARGS}")
if(DEFINED FILE)
  file(REMOVE "${FILE}")
endif()
execute_process(COMMAND "${CMD}" ${args} RESULT_VARIABLE rc OUTPUT_VARIABLE out
  ERROR_VARIABLE err)
set(both "${out}${err}")
if(NOT rc STREQUAL "${EXIT}")
  message(FATAL_ERROR "exit code ${rc}, expected ${EXIT}\n--- stdout:\n${out}\n--- stderr:\n${err}")
endif()
if(DEFINED REGEX AND NOT both MATCHES "${REGEX}")
  message(FATAL_ERROR "output does not match '${REGEX}'\n--- stdout:\n${out}\n--- stderr:\n${err}")
endif()
if(DEFINED FILE)
  if(NOT EXISTS "${FILE}")
    message(FATAL_ERROR "${FILE} was not written\n--- stderr:\n${err}")
  endif()
  file(READ "${FILE}" content)
  if(NOT content MATCHES "${FILE_REGEX}")
    message(FATAL_ERROR "${FILE} does not match '${FILE_REGEX}':\n${content}")
  endif()
endif()
