// The translation unit that tests/CMakeLists.txt's markerd_test_pch compiles
// its precompiled header with; every test executable reuses that header.
