MNI Tag Point File
Volumes = 2;
% Volume 1 produced by VTK
% Volume 2 produced by VTK

Points =
 -12.34 56.78 -9.01 -11.1 57.9 -8.2 1 1 101 "AC"
 23.45 -67.89 10.12 24.6 -66.05 11.7 0.5 2 101 "PC"
 -34.56 -7.8 90.12 -33.3 -6.45 91.4 2.25 7 102 "vertex"
 0.1 0.2 -0.3 1.05 0.7 0.15 0 -1 -1 "origin";
