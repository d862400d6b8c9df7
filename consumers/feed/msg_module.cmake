# cmake -DINPUT=F -DOUTPUT=G -P msg_module.cmake: one lcm-gen Python file (types/, package
# `stackgen`) made a module of the subpackage stackgen.msg: its references to the other message
# types (`import stackgen.header`, `stackgen.header._decode_one(buf)`) become stackgen.msg.X, so
# the message types live apart from the package's own names (stackgen.msg.scene, the LCM class;
# stackgen.Scene, the stream's scene).
file(READ ${INPUT} text)
string(REGEX REPLACE "stackgen\\.([a-z_]+)" "stackgen.msg.\\1" text "${text}")
file(WRITE ${OUTPUT} "${text}")
