"""The CPU record stored with every timing (hybridpose.machine)."""
import os

from hybridpose.machine import ISA_FLAGS, cpu_label, describe_cpu

X86 = """processor\t: 0
vendor_id\t: AuthenticAMD
model name\t: AMD EPYC 9B14
flags\t\t: fpu sse2 avx avx2 fma avx512f avx512_bf16
processor\t: 1
model name\t: AMD EPYC 9B14
flags\t\t: fpu sse2
"""
ARM = """processor\t: 0
BogoMIPS\t: 50.00
Features\t: fp asimd evtstrm aes sve
"""


def test_describe_cpu_reads_the_first_processors_model_and_isa(tmp_path):
    f = tmp_path / "cpuinfo"
    f.write_text(X86)
    rec = describe_cpu(f)
    assert rec["cpu_model"] == "AMD EPYC 9B14"
    assert rec["isa"] == ["avx2", "fma", "avx512f", "avx512_bf16"]   # ISA_FLAGS' order, first processor's flags
    assert rec["cpus"] == os.cpu_count()
    assert cpu_label(rec).startswith(f"AMD EPYC 9B14, {os.cpu_count()} CPUs")


def test_describe_cpu_without_cpuinfo_or_model_name_still_names_something(tmp_path):
    f = tmp_path / "cpuinfo"
    f.write_text(ARM)
    rec = describe_cpu(f)
    assert rec["cpu_model"] and rec["isa"] == []                     # ARM: no x86 flags, model from platform
    rec = describe_cpu(tmp_path / "missing")
    assert rec["cpu_model"] and rec["isa"] == []
    assert set(rec["isa"]) <= set(ISA_FLAGS)


def test_cpu_label_of_an_empty_record():
    assert cpu_label({}) == "unknown CPU"
    assert cpu_label({"cpu_model": "X", "cpus": 2, "torch_cpu_capability": "AVX2"}) == "X, 2 CPUs, AVX2"
