from kx.native import main

main()
