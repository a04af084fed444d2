# [F] Figure 10 on this machine: the monoped's OCP (bench/monoped_benchmark.cc), total CPU time
# of the homotopy, CPU time per IPOPT iteration and the smallest sigma whose NLP was solved against
# N, step and Stewart formulations.
# Data: monoped_cpu.csv (scripts/bench --monoped). Run in docs/: gnuplot monoped_cpu.gp
set encoding utf8
set terminal pngcairo size 1500,480 enhanced font 'Sans,12'
set output 'monoped_cpu.png'
set datafile separator ','
set multiplot layout 1,3 title 'The monoped of [F] Section 7.2 on 2 cores with MUMPS (filled: solved with two hops or more, open: not; each homotopy within the IPOPT iteration budget of the CSV)'
set grid lc rgb '#dddddd'
set key top left
set xlabel 'N (control stages)'
set xrange [25:95]
set ylabel 'CPU time of the homotopy [s]'
ok(f) = strcol(1) eq f && strcol(3) eq 'solved' && $4 >= 2
plot 'monoped_cpu.csv' skip 1 using (ok('step') ? $2 : NaN):8 with points pt 7 ps 1.3 lc rgb '#1f77b4' title 'step', \
     '' skip 1 using (strcol(1) eq 'step' && !ok('step') ? $2 : NaN):8 with points pt 6 ps 1.3 lc rgb '#1f77b4' notitle, \
     '' skip 1 using (ok('stewart') ? $2 : NaN):8 with points pt 5 ps 1.3 lc rgb '#d62728' title 'Stewart', \
     '' skip 1 using (strcol(1) eq 'stewart' && !ok('stewart') ? $2 : NaN):8 with points pt 4 ps 1.3 lc rgb '#d62728' notitle
set ylabel 'CPU time per IPOPT iteration [ms]'
plot 'monoped_cpu.csv' skip 1 using (strcol(1) eq 'step' ? $2 : NaN):9 with linespoints pt 7 ps 1.3 lc rgb '#1f77b4' title 'step', \
     '' skip 1 using (strcol(1) eq 'stewart' ? $2 : NaN):9 with linespoints pt 5 ps 1.3 lc rgb '#d62728' title 'Stewart'
set ylabel 'smallest {/Symbol s} solved'
set key bottom right
set logscale y
set yrange [*:2]
set format y '10^{%L}'
plot 'monoped_cpu.csv' skip 1 using (strcol(1) eq 'step' ? $2 : NaN):17 with linespoints pt 7 ps 1.3 lc rgb '#1f77b4' title 'step', \
     '' skip 1 using (strcol(1) eq 'stewart' ? $2 : NaN):17 with linespoints pt 5 ps 1.3 lc rgb '#d62728' title 'Stewart'
unset logscale y
set yrange [*:*]
set format y '%g'
unset multiplot
