#!/bin/bash
# usage: run.sh tag inject flux [extra sets...]
tag=$1; inj=$2; flux=$3; shift 3
line="$tag:"
for s in cube06 fs5g6 fs5g9 bs5g6 bs5g9 bs20g9 ${CLOUD:+cloud}; do
  ./sl2 render $s.toml --solver lbl --set lbl.grid=${GRID:-64} --set lbl.inject=$inj --set lbl.flux=$flux "$@" --out $tag-$s.exr > log-$tag-$s 2>&1 || { line="$line $s FAIL"; continue; }
  r=$(./sl2 compare $tag-$s.exr ref-$s.exr 2>&1 | awk '/^bias relL2/{b=$3} /^energy ratio/{e=$3} END{printf "%.3f/%.3f", e, b}')
  line="$line $s $r"
done
echo "$line"
