MNI Tag Point File
Volumes = 2;
% Volume 1: subject01_t1.mnc
% Volume 2: icbm152_t1.mnc
%written by data-scripts/mni_vtk.py

Points =
 5.5 -6.6 7.7 6 -6.1 8.2 "a"
 -8.8 9.9 -10.1 -8.3 10.4 -9.6 "b"
 11.11 -12.12 13.13 11.6 -11.62 13.63 "c";
